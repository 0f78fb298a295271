"""The generated reference pages match the code: docs/reference.md (the CLI parser and the config dataclasses),
docs/recipe.md (the recipe's sections and keys) and docs/api.md (the public Python objects)."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def _generator():
    spec = importlib.util.spec_from_file_location("gen_reference", ROOT / "scripts" / "gen_reference.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


GEN = _generator()


@pytest.mark.parametrize("page", list(GEN.PAGES), ids=lambda p: str(p.relative_to(ROOT)))
def test_each_generated_page_matches_the_code(page):
    expected = GEN.PAGES[page]()
    current = page.read_text() if page.exists() else ""
    assert current == expected, f"{page.relative_to(ROOT)} is stale; regenerate it with `{GEN.COMMAND}`"


def test_the_reference_names_every_subcommand_and_config_field():
    import dataclasses

    from drem_maniskill.pipeline.train_reward import TrainConfig
    from drem_maniskill.rl.config import RLConfig

    text = GEN.render()
    for command in ("sample", "train-reward", "train-policy", "sweep", "build-reward", "examine", "demo"):
        assert f"### `drem-maniskill {command}`" in text
    for cls in (TrainConfig, RLConfig):
        for f in dataclasses.fields(cls):
            assert f"| `{f.name}` |" in text


def _keys(table: dict, prefix: str = ""):
    """Every ``(section path, key)`` of ``valid_keys()``, nested tables (``model``, ``phases.<name>``) included."""
    for key, value in table.items():
        if isinstance(value, dict) and value:
            yield from _keys(value, f"{prefix}{key}.")
        else:
            yield prefix, key


def test_the_recipe_page_names_and_explains_every_section_and_key():
    from drem_maniskill.pipeline.recipe import SECTIONS, valid_keys

    text = GEN.render_recipe()
    assert GEN.UNDOCUMENTED not in text, "a recipe key has no description: give its field a docstring (or KEY_DOCS)"
    valid = valid_keys()
    for section in SECTIONS:
        assert f"## `[{section}]`" in text
        for path, key in _keys(valid.get(section, {})):
            if path:
                assert f"`[{section}.{path.rstrip('.')}]`" in text, (section, path)
            assert f"| `{key}` |" in text, (section, path, key)


def test_the_api_page_shows_each_public_object_with_its_docstring():
    import importlib
    import inspect

    text = GEN.render_api()
    for module, name in GEN.API:
        obj = getattr(importlib.import_module(module), name)
        assert f"## `{name}`" in text and f"from {module} import {name}" in text
        first_line = (inspect.getdoc(obj) or "").splitlines()[0]
        assert GEN._md(first_line) in text, name
