"""Learning curves compared: steps to a level, the plot and table, the comparison script."""

from __future__ import annotations

import csv
import json

import pytest

from drem_maniskill.rl.compare import compare_runs, steps_to_reach
from drem_maniskill.rl.train_policy import EVAL_COLUMNS


def test_steps_to_reach_is_the_first_evaluation_at_the_level():
    assert steps_to_reach([0, 1000, 2000, 3000], [0.0, 0.2, 0.6, 1.0]) == 2000
    assert steps_to_reach([0, 1000, 2000], [0.0, 0.5, 0.4]) == 1000
    assert steps_to_reach([0, 1000], [0.0, 0.4]) is None
    assert steps_to_reach([0, 1000], [0.5, 0.9]) == 0


def _fake_run(root, task, reward, seed, curve, every=1000):
    run = root / f"{task}-{reward}-{seed}"
    run.mkdir(parents=True)
    (run / "config.json").write_text(json.dumps(dict(task=task, reward=reward, seed=seed)))
    with (run / "eval.csv").open("w", newline="") as f:
        w = csv.writer(f)
        w.writerow(EVAL_COLUMNS)
        for i, s in enumerate(curve):
            w.writerow([i * every, s, 0.0, float(i)])
    return run


def test_compare_two_fake_runs(tmp_path):
    runs = [_fake_run(tmp_path, "PegInHole-v1", "drem", 0, [0.0, 0.2, 0.6, 1.0]),
            _fake_run(tmp_path, "PegInHole-v1", "drem", 1, [0.0, 0.4, 0.8, 1.0]),
            _fake_run(tmp_path, "PegInHole-v1", "sparse", 0, [0.0, 0.0, 0.1, 0.2]),
            _fake_run(tmp_path, "USBInsertion-v1", "drem", 0, [0.0, 0.5, 0.5, 0.5])]
    result = compare_runs(runs, str(tmp_path / "cmp"))
    assert (tmp_path / "cmp" / "comparison.png").stat().st_size > 10_000
    rows = {(r["task"], r["reward"]): r for r in json.loads((tmp_path / "cmp" / "comparison.json").read_text())["rows"]}
    # Mean of the two drem seeds: 0, 0.3, 0.7, 1.0: first at or above 0.5 at step 2000.
    assert rows[("PegInHole-v1", "drem")]["steps_to_50"] == 2000
    assert rows[("PegInHole-v1", "drem")]["seeds"] == 2
    # 80 %: the mean first at 3000; seed 0 at 3000 (1.0), seed 1 at 2000 (0.8).
    assert rows[("PegInHole-v1", "drem")]["steps_to_80"] == 3000
    assert rows[("PegInHole-v1", "drem")]["seed_steps_to_80"] == [3000, 2000]
    assert rows[("PegInHole-v1", "drem")]["seed_ids"] == [0, 1]
    assert rows[("PegInHole-v1", "sparse")]["seed_steps_to_50"] == ["not reached"]
    assert "| 2000; 2000 / 2000 | 3000; 3000 / 2000 |" in open(result["markdown"]).read()
    assert rows[("PegInHole-v1", "sparse")]["steps_to_50"] == "not reached"
    assert rows[("PegInHole-v1", "sparse")]["final_success"] == pytest.approx(0.2)
    assert rows[("USBInsertion-v1", "drem")]["steps_to_50"] == 1000
    assert "not reached" in open(result["markdown"]).read()


def test_runs_that_end_at_success_or_use_another_checkpoint_are_curves_of_their_own(tmp_path):
    plain = _fake_run(tmp_path, "PegInHole-v1", "engineered", 0, [0.0, 0.2, 0.4])
    ended = _fake_run(tmp_path / "t", "PegInHole-v1", "engineered", 0, [0.0, 0.6, 1.0])
    own = _fake_run(tmp_path / "c", "PegInHole-v1", "drem", 0, [0.0, 0.0, 0.0])
    tuned = _fake_run(tmp_path / "k", "PegInHole-v1", "drem", 0, [0.0, 0.1, 0.1])
    trap = _fake_run(tmp_path / "p", "PegInHole-v1", "drem", 0, [0.0, 0.0, 0.0])
    fewer = _fake_run(tmp_path / "f", "PegInHole-v1", "engineered", 0, [0.0, 0.0, 0.2])
    overlapped = _fake_run(tmp_path / "o", "PegInHole-v1", "engineered", 0, [0.0, 0.0, 0.4])
    vice = _fake_run(tmp_path / "v", "PegInHole-v1", "vice", 0, [0.0, 0.0, 0.0])
    # An unset form under termination is the shifted one (RLConfig.drem_form_used); the paper's is then named too.
    knobs = dict(drem_form=None, terminate_on_success=True, obs_norm=["state", "ft"], action_scale=0.5)
    for run, extra in ((ended, dict(terminate_on_success=True)), (own, dict(reward_checkpoint="out/reward/drem.pt")),
                       (tuned, knobs), (trap, dict(drem_form="paper", terminate_on_success=True)),
                       (fewer, dict(train_freq=4, train_bf16=True)), (overlapped, dict(overlap_env=True)),
                       (vice, dict(overlap_env=True))):
        cfg = json.loads((run / "config.json").read_text())
        (run / "config.json").write_text(json.dumps({**cfg, **extra}))
    runs = [plain, ended, own, tuned, trap, fewer, overlapped, vice]
    table = {r["reward"]: r for r in compare_runs(runs, str(tmp_path / "cmp"))["rows"]}
    assert set(table) == {"engineered", "engineered, ends at success", "drem (out/reward/drem.pt)",
                          "drem, shifted, ends at success, norm state+ft, actions x0.5", "drem, paper, ends at success",
                          "engineered, updates x0.25, bf16", "engineered, overlapped",
                          "vice"}  # a learned reward's env stays in the run's process: nothing overlapped
    assert table["engineered, ends at success"]["steps_to_50"] == 1000
    assert table["engineered"]["steps_to_50"] == "not reached"


def test_the_settings_every_curve_of_a_panel_shares_go_to_its_title():
    from drem_maniskill.rl.compare import shared_settings

    labels = ["drem (a.pt), shifted, ends at success, norm state+ft", "drem, shifted, ends at success, norm state+ft",
              "engineered, ends at success, norm state+ft"]
    assert shared_settings(labels) == ["ends at success", "norm state+ft"]
    assert shared_settings(["sparse"]) == []
    assert shared_settings(["drem, shifted", "drem, paper"]) == []


def test_runs_are_grouped_by_the_checkpoint_file_that_paid_them(tmp_path):
    """A copy of the shipped checkpoint joins the reward's curve; a run pinned to another file gets its own."""
    import shutil

    from drem_maniskill.rl.compare import load_run
    from drem_maniskill.rl.rewards import reward_checkpoint
    from drem_maniskill.rl.train_policy import file_sha256

    shipped = reward_checkpoint("drem", "PegInHole-v1")
    copy = tmp_path / "copy.pt"
    shutil.copy(shipped, copy)
    other = tmp_path / "other.pt"
    other.write_bytes(shipped.read_bytes() + b"retrained")
    labels = {}
    for name, path, given in (("default", shipped, None), ("copy", copy, str(copy)), ("old", other, None),
                              ("unpinned", None, "out/reward/drem.pt")):
        run = _fake_run(tmp_path / name, "PegInHole-v1", "drem", 0, [0.0, 0.5, 1.0])
        cfg = json.loads((run / "config.json").read_text())
        (run / "config.json").write_text(json.dumps({**cfg, "reward_checkpoint": given}))
        if path is not None:
            (run / "reward_checkpoint.json").write_text(json.dumps(dict(path=str(path), sha256=file_sha256(path))))
        labels[name] = load_run(run)["reward"]
    assert labels["default"] == labels["copy"] == "drem"
    assert labels["old"] == f"drem (checkpoint {file_sha256(other)[:8]})"
    assert labels["unpinned"] == "drem (out/reward/drem.pt)"  # runs made before the pin: named by the path given


def test_a_run_label_names_only_the_inputs_its_policy_normalised():
    """The image preset normalises state and F/T, but only DREM's policy gets the F/T history."""
    from drem_maniskill.rl.compare import run_label
    from drem_maniskill.rl.config import RLConfig

    labels = {r: run_label(RLConfig.from_preset("image", reward=r).to_dict()) for r in ("sparse", "drem")}
    assert "norm state," in labels["sparse"] + "," and "norm state+ft" not in labels["sparse"]
    assert "norm state+ft" in labels["drem"]
    # Every policy gets it.
    assert "norm state+ft" in run_label(RLConfig.from_preset("light", reward="sparse").to_dict())
    stock = run_label(RLConfig.from_preset("state", task="PushCube-v1", reward="drem").to_dict())
    assert "norm state," in stock + "," and "+ft" not in stock  # a stock task has no F/T sensor
