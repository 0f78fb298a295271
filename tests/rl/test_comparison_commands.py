"""The documented commands still make the committed state- and image-preset comparisons (docs/results.md)."""

from __future__ import annotations

import argparse
import hashlib
import json
from pathlib import Path

import pytest

from drem_maniskill.drem.checkpoint import resolve_checkpoint
from drem_maniskill.rl.__main__ import add_subcommands
from drem_maniskill.rl.sweep import configs_from_args

ROOT = Path(__file__).resolve().parents[2]
RUNS = sorted((ROOT / "docs/results/comparison_state").glob("*/*/seed*/config.json"))
# Switches added after some committed runs were made; those runs ran with them off, as the command turns them off.
LATER_SWITCHES = {"train_bf16": False, "overlap_env": False, "shared_encoder": False}


def _command_config(saved: dict) -> dict:
    """The config of the trial docs/results.md's sweep starts (--preset state --no-bf16 --no-overlap-env)."""
    parser = argparse.ArgumentParser()
    add_subcommands(parser.add_subparsers(dest="command"))
    args = parser.parse_args([
        "sweep", "--tasks", saved["task"], "--rewards", saved["reward"], "--seeds", str(saved["seed"]),
        "--steps", "50000", "--preset", "state", "--no-bf16", "--no-overlap-env", "--out", "outputs/rl"])
    (config,) = configs_from_args(args)
    return config.to_dict()


IMAGE_RUNS = sorted((ROOT / "docs/results/comparison_image").glob("*/*/seed*/config.json"))


@pytest.mark.parametrize("path", IMAGE_RUNS, ids=lambda p: "/".join(p.parts[-4:-1]))
def test_the_image_comparison_command_makes_each_committed_runs_config(path):
    """docs/results.md's sweep of the image comparison, run to 50,000 steps."""
    saved = json.loads(path.read_text())
    parser = argparse.ArgumentParser()
    add_subcommands(parser.add_subparsers(dest="command"))
    args = parser.parse_args(["sweep", "--tasks", saved["task"], "--rewards", saved["reward"], "--seeds",
                              str(saved["seed"]), "--steps", "50000", "--preset", "image", "--out", "outputs/rl_image"])
    (config,) = configs_from_args(args)
    made = config.to_dict()
    assert saved.pop("out") == made.pop("out")
    assert made == saved
    rows = (path.parent / "eval.csv").read_text().splitlines()
    assert rows[-1].split(",")[0] == "50000" and len(rows) == 1 + 50_000 // 2_500 + 1  # header, 0, every 2,500
    record = path.parent / "reward_checkpoint.json"
    if saved["reward"].startswith("drem"):
        shipped = resolve_checkpoint(saved["task"], image_only=saved["reward"] == "drem-image")
        assert json.loads(record.read_text())["sha256"] == hashlib.sha256(shipped.read_bytes()).hexdigest()


def test_every_committed_run_is_counted():
    assert len(RUNS) == 30  # 2 tasks x 5 rewards x 3 seeds


@pytest.mark.parametrize("path", RUNS, ids=lambda p: "/".join(p.parts[-4:-1]))
def test_the_documented_command_makes_the_committed_runs_config(path):
    saved = json.loads(path.read_text())
    made = _command_config(saved)
    for key, value in LATER_SWITCHES.items():
        saved.setdefault(key, value)
    # The checkpoint a DREM run read is pinned by its sha256 below: the runs named the file by a local path.
    saved.pop("reward_checkpoint")
    made.pop("reward_checkpoint")
    # Where a run lies is no setting of it (a resume may name another --out): the committed runs were made in
    # scratch folders, some of other names, and copied here; the sweep puts each in <out>/<task>/<reward>/seed<S>.
    assert made.pop("out") == f"outputs/rl/{saved['task']}/{saved['reward']}/seed{saved['seed']}"
    saved.pop("out")
    assert made == saved
    record = path.parent / "reward_checkpoint.json"
    if record.exists():
        shipped = resolve_checkpoint(saved["task"], image_only=saved["reward"] == "drem-image")
        assert json.loads(record.read_text())["sha256"] == hashlib.sha256(shipped.read_bytes()).hexdigest()
