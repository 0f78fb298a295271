"""docs/reference.md is generated from the CLI parser and the config dataclasses: it must match them."""

from __future__ import annotations

import importlib.util
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _generator():
    spec = importlib.util.spec_from_file_location("gen_reference", ROOT / "scripts" / "gen_reference.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_the_reference_page_matches_the_code():
    gen = _generator()
    expected = gen.render()
    current = (ROOT / "docs" / "reference.md").read_text()
    assert current == expected, f"docs/reference.md is stale; regenerate it with `{gen.COMMAND}`"


def test_the_reference_names_every_subcommand_and_config_field():
    import dataclasses

    from drem_maniskill.pipeline.train_reward import TrainConfig
    from drem_maniskill.rl.config import RLConfig

    text = _generator().render()
    for command in ("sample", "train-reward", "train-policy", "sweep", "build-reward", "examine", "demo"):
        assert f"### `drem-maniskill {command}`" in text
    for cls in (TrainConfig, RLConfig):
        for f in dataclasses.fields(cls):
            assert f"| `{f.name}` |" in text
