"""check-reward: a short SAC run on a reward, and whether it pays failures like success."""

from __future__ import annotations

import json

import pytest

from drem_maniskill.cli import main
from drem_maniskill.drem.checkpoint import default_checkpoint
from drem_maniskill.evaluate.check_reward import CheckConfig, judge, markdown_table

EXPERT = {0: dict(success=True, end_reward=1.0), 1: dict(success=True, end_reward=0.9)}  # ends at 0.95 on average


def _row(success: bool, end: float) -> dict:
    return dict(seed=0, success=success, mean_reward=end / 2, end_reward=end)


def test_failures_paid_like_the_expert_are_an_exploit_and_cheap_ones_are_not():
    config = CheckConfig(paid_fraction=0.8, exploit_share=0.3)
    paid = judge([_row(False, 0.9), _row(False, 0.2), _row(True, 1.0)], EXPERT, config)
    assert paid["paid_threshold"] == pytest.approx(0.76) and paid["paid_failures"] == 1
    assert paid["exploit"] and paid["success_rate"] == pytest.approx(1 / 3)
    cheap = judge([_row(False, 0.5), _row(False, 0.2), _row(True, 1.0)], EXPERT, config)
    assert not cheap["exploit"] and cheap["failed_end_reward"] == pytest.approx(0.35)
    # One paid failure in ten episodes is a near miss, not a reward that pays for the wrong thing.
    rare = judge([_row(False, 0.9)] + [_row(True, 1.0)] * 9, EXPERT, config)
    assert rare["paid_failures"] == 1 and not rare["exploit"]


def test_an_evaluation_paid_without_success_is_an_exploit():
    """Return against success along the run: a policy paid 0.99 a step with no success has found something."""
    config = CheckConfig()
    curve = [dict(steps=0, success_rate=0.0, reward_per_step=0.99), dict(steps=600, success_rate=0.0,
                                                                        reward_per_step=0.2)]
    verdict = judge([_row(False, 0.1)], EXPERT, config, curve)
    assert verdict["paid_evaluations"] == [0] and verdict["exploit"]
    learning = [dict(steps=0, success_rate=0.0, reward_per_step=0.1), dict(steps=600, success_rate=0.5,
                                                                          reward_per_step=0.9)]
    assert not judge([_row(True, 1.0)], EXPERT, config, learning)["exploit"]
    assert not judge([_row(False, 0.9)], None, config, curve)["exploit"]  # no expert: nothing to compare with


def test_a_run_too_short_to_learn_is_refused():
    with pytest.raises(ValueError, match="must exceed --learning-starts"):
        CheckConfig(steps=500, learning_starts=1000)


def test_the_model_card_table_reads_the_report():
    config = CheckConfig()
    rows = [dict(_row(False, 0.9), seed=10000), dict(_row(True, 1.0), seed=10001)]
    curve = [dict(steps=0, success_rate=0.0, reward_per_step=0.99), dict(steps=2500, success_rate=0.5,
                                                                         reward_per_step=0.8)]
    report = dict(verdict=judge(rows, EXPERT, config, curve), sac=dict(curve=curve), episodes=rows,
                  config=dict(seed=3, paid_fraction=0.8))
    table = markdown_table(report)
    assert "| SAC (state preset, seed 3) along its run: steps: success, R per step | 0: 0%, 0.99; 2,500: 50%, 0.80 |" \
        in table
    assert "held-out seeds 10000-10001: success, mean R per step | 50%, 0.475 |" in table
    assert "| paid failures (end R >= 0.760, 0.8 x the expert's) | 1 of 2 |" in table
    assert "| evaluations paid like success without any | 0 |" in table and "| verdict | EXPLOIT" in table


def test_a_folder_that_is_not_a_finished_run_is_refused(tmp_path):
    from drem_maniskill.evaluate.check_reward import check_reward
    from drem_maniskill.rl.config import RLConfig

    with pytest.raises(FileNotFoundError, match="is not a train-policy run"):
        check_reward(CheckConfig(run=str(tmp_path)))
    config = RLConfig.from_preset("image", task="PegInHole-v1", reward="sparse", out=str(tmp_path))
    config.save(tmp_path / "config.json")
    with pytest.raises(FileNotFoundError, match="holds no policy checkpoint"):
        check_reward(CheckConfig(run=str(tmp_path)))


# 600 steps: 100 gradient steps after 500 random ones, evaluations at 0 and 600.
SMALL = ["--steps", "600", "--learning-starts", "500", "--eval-every", "600", "--eval-episodes", "1"]


@pytest.mark.slow
def test_the_shipped_plug_charger_reward_is_reported_as_exploited(tmp_path, capsys):
    """Its policies are paid about 0.99 a step without the plug ever going in (docs/results.md)."""
    # Paid like success from the first evaluation on: 20 steps, two evaluations, show it (each step renders two
    # cameras, and each evaluation is a 200-step episode).
    steps = ["--steps", "20", "--learning-starts", "10", "--eval-every", "20", "--eval-episodes", "1"]
    assert main(["check-reward", "--task", "PlugCharger-v1", "--episodes", "1", "--out", str(tmp_path), *steps]) == 0
    out = capsys.readouterr().out
    report = json.loads((tmp_path / "report.json").read_text())
    v = report["verdict"]
    assert v["exploit"] and "EXPLOIT" in out, out
    assert v["success_rate"] == 0 and v["expert_success_rate"] == 1
    assert v["paid_evaluations"] and all(c["success_rate"] == 0 for c in report["sac"]["curve"])


@pytest.mark.slow
def test_a_reward_that_teaches_reports_no_exploit(tmp_path, capsys):
    """The shipped PegInHole-v1 reward: a barely trained policy fails, and is paid little for it."""
    assert main(["check-reward", "--task", "PegInHole-v1", "--episodes", "2", "--out", str(tmp_path), *SMALL]) == 0
    out = capsys.readouterr().out
    v = json.loads((tmp_path / "report.json").read_text())["verdict"]
    assert not v["exploit"] and "no exploit found" in out, out
    assert v["expert_success_rate"] == 1 and v["paid_failures"] == 0
    assert "part tip" in out and "m from the expert's end" in out  # the held peg: where its tip is in the socket
    report = json.loads((tmp_path / "report.json").read_text())
    failed = [e for e in report["episodes"] if not e["success"]]
    assert failed and all({"insertion_depth", "radial_offset", "tilt_error", "yaw_error"} <= set(e["task_measures"])
                          for e in failed)
    # Read at the episode's end, they agree it failed: short of 0.8 x the 40 mm bore, or not aligned.
    assert all(e["task_measures"]["insertion_depth"] < 0.032 or not e["task_measures"]["is_aligned"] for e in failed)
    assert "the task's evaluate(): " in out and "insertion_depth" in out

    # The same run examined again as a finished run: nothing trained, the same policy on the same seeds; compared
    # with its own checkpoint, the compared reward pays every end what the run's reward pays it.
    first = json.loads((tmp_path / "report.json").read_text())
    shipped = str(default_checkpoint("PegInHole-v1"))
    assert main(["check-reward", "--run", str(tmp_path / "sac"), "--episodes", "2", "--out", str(tmp_path / "again"),
                 "--compare", shipped]) == 0
    out = capsys.readouterr().out
    assert f"report: {tmp_path / 'again' / 'report.json'}" in out and f"under {shipped}: failed episodes end" in out
    again = json.loads((tmp_path / "again" / "report.json").read_text())
    assert again["sac"]["steps"] == 600 and again["sac"]["preset"] == "state" and again["reward"] == "drem"
    assert [(e["success"], round(e["end_reward"], 5)) for e in again["episodes"]] == \
        [(e["success"], round(e["end_reward"], 5)) for e in first["episodes"]]
    assert all(e["compare_end_reward"] == pytest.approx(e["end_reward"], abs=1e-4) for e in again["episodes"])
    compared = again["verdict"]["compare"]
    assert compared["checkpoint"] == shipped
    assert compared["failed_end_reward"] == pytest.approx(again["verdict"]["failed_end_reward"], abs=1e-4)
    assert compared["expert_end_reward"] == pytest.approx(again["verdict"]["expert_end_reward"], abs=1e-4)
    assert "compare" not in first["verdict"]
