"""The command line end to end at a tiny scale, as a user runs it (subprocesses)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import h5py
import pytest


def run(*args, cwd=None) -> str:
    """Run ``drem-maniskill ARGS`` with this interpreter; fail with its output."""
    proc = subprocess.run([sys.executable, "-m", "drem_maniskill.cli", *args], capture_output=True, text=True, cwd=cwd, timeout=900)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    return proc.stdout


def test_help_of_every_subcommand():
    for cmd in ("demo", "record-expert", "scripted-success", "examine", "sample", "train-reward"):
        assert "usage: drem-maniskill " + cmd in run(cmd, "--help")


@pytest.mark.slow
def test_chain_record_sample_train_examine(tmp_path):
    run("record-expert", "--task", "USBInsertion-v1", "--seed", "1000", "--out", str(tmp_path / "expert"))
    expert = tmp_path / "expert" / "expert.h5"
    assert json.loads((tmp_path / "expert" / "expert.json").read_text())["env_info"]["env_id"] == "USBInsertion-v1"
    out = run("sample", "--expert", str(expert), "--out", str(tmp_path / "tree.h5"), "--preset", "tiny")
    assert "progress tree:" in out
    with h5py.File(tmp_path / "tree.h5", "r") as f:
        assert f["in_start_region"][()].any()
    out = run("train-reward", "--dataset", str(tmp_path / "tree.h5"), "--out", str(tmp_path / "reward"), "--preset", "tiny")
    assert (tmp_path / "reward" / "drem.pt").exists()
    out = run("examine", "--task", "USBInsertion-v1", "--checkpoint", str(tmp_path / "reward" / "drem.pt"),
              "--out", str(tmp_path / "exam"), "--episodes", "1")
    quality = json.loads((tmp_path / "exam" / "quality.json").read_text())
    assert set(quality["curves"]) == {"direct_success", "align_success", "search_fail", "random"}
    assert quality["success_rate"]["direct_success"] == 1.0
    assert -1 <= quality["spearman_with_normalized_dense"] <= 1 and -1 <= quality["spearman_with_insertion_depth"] <= 1
    assert len(quality["dense_curves"]["random"][0]) == len(quality["curves"]["random"][0])
    from drem_maniskill.pipeline.examine import (
        FACE_PUSHED, HOLD_POSITIONS, SIDE_POSITION, SIDE_PUSHED, TURNED_HOVER, UPRIGHT_HOVER,
    )

    held = quality["held_positions"]
    floor = "pressed on the floor, 75 mm beside"
    assert list(held) == [*HOLD_POSITIONS, floor, SIDE_POSITION, SIDE_PUSHED, FACE_PUSHED, TURNED_HOVER, UPRIGHT_HOVER, "inserted"]
    assert quality["turned_over_upright"] == pytest.approx(held[TURNED_HOVER]["mean"] / held[UPRIGHT_HOVER]["mean"])
    assert quality["turned_over_inserted"] == pytest.approx(held[TURNED_HOVER]["mean"] / held["inserted"]["mean"])
    assert all(v["reached_error_mm"] < 2.0 for k, v in held.items() if k not in ("inserted", SIDE_PUSHED) and "beside" not in k)
    # Pressed on the floor: 2 mm short of the target below it, nowhere else.
    assert 1.0 < held[floor]["reached_error_mm"] < 3.0
    assert quality["floor_beside_over_inserted"] == pytest.approx(held[floor]["mean"] / held["inserted"]["mean"])
    assert held[SIDE_POSITION]["reached_error_mm"] < 0.5  # beside the block's side, clear of it
    assert quality["side_over_inserted"] == pytest.approx(held[SIDE_POSITION]["mean"] / held["inserted"]["mean"])
    # Pushed into the block's side and down: the plug's overmould stops on the block's edge, 8 mm above the target.
    assert 7.0 < held[SIDE_PUSHED]["reached_error_mm"] < 9.0
    assert quality["side_pushed_over_inserted"] == pytest.approx(held[SIDE_PUSHED]["mean"] / held["inserted"]["mean"])
    assert 8.0 < held[FACE_PUSHED]["reached_error_mm"] < 11.0  # on the face, 8 mm above its target and slid out
    assert quality["face_pushed_over_inserted"] == pytest.approx(held[FACE_PUSHED]["mean"] / held["inserted"]["mean"])
    assert quality["face_over_hover"] == pytest.approx(held["pressed 3 mm beside"]["mean"] / held["4 mm above, 4 mm off"]["mean"])
    assert quality["colour_spread"]["max_std"] == max(v["std"] for k, v in held.items() if k != "inserted")
    assert {"episodes", "mean_reward", "direct_success_final", "fraction"} <= set(quality["contact_plateau"])
    assert set(quality["contact_plateau"]) - {"episodes", "mean_reward", "direct_success_final", "fraction"} <= {"on_face", "at_opening"}
    assert (tmp_path / "exam" / "examination.png").stat().st_size > 10_000


@pytest.mark.slow
def test_demo_writes_its_plots(tmp_path):
    out = run("demo", "--out", str(tmp_path / "demo"), "--tasks", "PegInHole-v1", "--episodes", "1", "--scale", "tiny")
    assert "reward checkpoint:" in out
    summary = json.loads((tmp_path / "demo" / "summary.json").read_text())
    for plot in summary["PegInHole-v1"]["plots"]:
        assert Path(plot).stat().st_size > 2_000, plot


@pytest.mark.parametrize("argv", [
    ["train-policy", "--task", "NoSuchTask-v1", "--steps", "8"],
    ["record-expert", "--task", "NoSuchTask-v1"],
    ["scripted-success", "--task", "NoSuchTask-v1"],
    ["examine", "--task", "NoSuchTask-v1", "--checkpoint", "none.pt"],
    ["demo", "--tasks", "PegInHole-v1", "NoSuchTask-v1"],
])
def test_an_unknown_task_id_is_one_error_line_listing_the_ids(argv, capsys, tmp_path, monkeypatch):
    from drem_maniskill.cli import main

    monkeypatch.chdir(tmp_path)  # nothing may be written, but if it were, not into the checkout
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"drem-maniskill {argv[0]}: error: unknown task id 'NoSuchTask-v1'. "
                          "Ours: PegInHole-v1, USBInsertion-v1, PegInHole-DREM-v1, USBInsertion-DREM-v1; ManiSkill's: ")
    assert "PegInsertionSide-v1" in err and "Traceback" not in err and err.count("\n") == 1
    assert not list(tmp_path.iterdir())


def test_a_misspelt_task_id_gets_a_suggestion(capsys):
    from drem_maniskill.rl.__main__ import main

    assert main(["train-policy", "--task", "PegInHoel-v1"]) == 2
    assert "Did you mean PegInHole-v1" in capsys.readouterr().err
