"""sweep: the grid's run folders and flags, bad names before Ray, and a tiny sweep on local Ray killed and resumed."""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from drem_maniskill.cli import main
from drem_maniskill.rl.config import RLConfig
from drem_maniskill.rl.sweep import log_path, plan_trials, run_sweep, split_finished
from drem_maniskill.rl.train_policy import read_eval_csv

# `make test` runs a test file on one xdist worker: one local Ray cluster at a time, as the CPU-share test needs.
# A 200-step light run: one held-out episode at steps 0, 100 and 200, gradient steps only after 150.
TINY = ["--steps", "200", "--eval-every", "100", "--eval-episodes", "1", "--learning-starts", "150",
        "--batch-size", "16"]


def _ray_started() -> bool:
    ray = sys.modules.get("ray")
    return ray is not None and ray.is_initialized()


@pytest.mark.parametrize("argv, message", [
    (["--tasks", "PegInHoel-v1", "--rewards", "sparse"], "unknown task id 'PegInHoel-v1'"),
    (["--tasks", "PegInHole-v1", "--rewards", "sparse", "spars"], "unknown reward 'spars'"),
])
def test_an_unknown_task_or_reward_fails_before_any_trial(tmp_path, capsys, argv, message):
    out = tmp_path / "sweep"
    assert main(["sweep", *argv, "--seeds", "0", "--out", str(out), *TINY]) == 2
    assert message in capsys.readouterr().err
    assert not out.exists() and not _ray_started()


def test_an_unknown_preset_fails_before_any_trial(tmp_path):
    with pytest.raises(ValueError, match="unknown preset 'huge'"):
        plan_trials(["PegInHole-v1"], ["sparse"], [0], 200, tmp_path, presets=["light", "huge"])
    assert not _ray_started()


def test_every_trial_gets_its_folder_and_the_train_policy_flags(tmp_path):
    configs = plan_trials(["PegInHole-v1", "USBInsertion-v1"], ["sparse", "drem"], [0, 1, 0], 300, tmp_path,
                          presets=["state", "light"], overrides=dict(eval_every=50, train_bf16=False))
    assert len(configs) == 2 * 2 * 2 * 2  # the repeated seed counts once
    assert {c.out for c in configs} == {str(tmp_path / p / t / r / f"seed{s}") for p in ("state", "light")
                                        for t in ("PegInHole-v1", "USBInsertion-v1") for r in ("sparse", "drem")
                                        for s in (0, 1)}
    # Seed 0 of every task and reward first: a grid cut short still compares them all.
    assert [(c.preset, c.task, c.seed, c.reward) for c in configs[:5]] == [
        ("state", "PegInHole-v1", 0, "sparse"), ("state", "PegInHole-v1", 0, "drem"),
        ("state", "USBInsertion-v1", 0, "sparse"), ("state", "USBInsertion-v1", 0, "drem"),
        ("state", "PegInHole-v1", 1, "sparse")]
    for c in configs:
        assert (c.steps, c.eval_every, c.train_bf16) == (300, 50, False)
        assert c.cameras == RLConfig.from_preset(c.preset).cameras
    (one,) = plan_trials(["PegInHole-v1"], ["drem"], [2], 300, tmp_path)
    assert one.out == str(tmp_path / "PegInHole-v1" / "drem" / "seed2") and one.preset == "light"


def _finished_run(config: RLConfig, steps: int) -> None:
    """A run folder as train_policy leaves it at ``steps`` (config, eval.csv, the checkpoint pointer)."""
    run = config.run_dir
    (run / "checkpoints" / f"step_{steps}").mkdir(parents=True)
    (run / "checkpoints" / "latest.json").write_text(json.dumps({"step": steps, "dir": f"step_{steps}"}))
    config.save(run / "config.json")
    (run / "eval.csv").write_text(f"steps,success_rate,mean_return,wall_time\n0,0.0,0.0,1.0\n{steps},0.5,1.0,9.0\n")


def test_trials_of_one_label_in_their_own_folders_get_their_own_logs(tmp_path):
    """Two drem trials of one task and seed, each paid by another checkpoint in its own folder, log apart; a grid
    trial keeps the ``<preset>-<task>-<reward>-seed<S>`` name."""
    runs = [RLConfig.from_preset("state", task="PegInHole-v1", reward="drem", seed=0,
                                 out=str(tmp_path / "PegInHole-v1" / variant / "seed0")) for variant in ("a", "b")]
    assert [log_path(tmp_path, c).name for c in runs] == ["state-PegInHole-v1-a-seed0.log",
                                                           "state-PegInHole-v1-b-seed0.log"]
    grid = RLConfig.from_preset("state", task="PegInHole-v1", reward="drem", seed=0,
                                out=str(tmp_path / "state" / "PegInHole-v1" / "drem" / "seed0"))
    assert log_path(tmp_path, grid).name == "state-PegInHole-v1-drem-seed0.log"


def test_a_finished_grid_is_skipped_without_ray(tmp_path, monkeypatch, capsys):
    configs = plan_trials(["PegInHole-v1"], ["sparse", "engineered"], [0], 200, tmp_path)
    for config in configs:
        _finished_run(config, 200)
    monkeypatch.setitem(sys.modules, "ray", None)  # any import of ray would fail
    result = run_sweep(configs, tmp_path)
    assert [t["status"] for t in result["trials"]] == ["skipped", "skipped"] and result["failed"] == 0
    assert "skip light PegInHole-v1 sparse seed0: finished, success 0.50 at 200 steps" in capsys.readouterr().out


def test_a_finished_run_kept_without_its_checkpoints_is_skipped(tmp_path, monkeypatch):
    """Committed results keep config.json and eval.csv only: a sweep on them skips the finished runs."""
    short, done, other = plan_trials(["PegInHole-v1"], ["sparse", "engineered", "drem"], [0], 200, tmp_path)
    for config, steps in ((short, 100), (done, 200), (other, 200)):
        _finished_run(config, steps)
        shutil.rmtree(config.run_dir / "checkpoints")
    RLConfig.from_dict({**other.to_dict(), "gamma": 0.5}).save(other.run_dir / "config.json")
    monkeypatch.setitem(sys.modules, "ray", None)
    todo, finished = split_finished([short, done])
    assert todo == [short] and [t["trial"] for t in finished] == ["light PegInHole-v1 engineered seed0"]
    with pytest.raises(ValueError, match="holds a run with another config"):
        split_finished([other])


@pytest.mark.slow
def test_trials_keep_to_their_cpu_share_while_reporting_their_start(tmp_path):
    """At most cores / cpus-per-trial trials at once: the start report must not lend a trial's CPU back to Ray."""
    ray = pytest.importorskip("ray")
    from ray.util.queue import Queue

    from drem_maniskill.rl.sweep import report_start

    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False)
    try:
        queue = Queue(actor_options={"num_cpus": 0})

        @ray.remote(num_cpus=1, max_calls=1)
        def trial(i):
            import torch  # a fresh worker per trial, slow to start as a real one: the queue's actor is not up yet

            t0 = time.time()
            report_start(queue, i)
            x = torch.randn(300, 300)
            while time.time() - t0 < 4:  # busy, as a trial is
                x = x @ x
                x = x / x.norm()
            return t0, time.time()

        spans = ray.get([trial.remote(i) for i in range(3)])  # two at a time: all three at once is a lent CPU
        reported = sorted(queue.get_nowait_batch(queue.qsize()))
    finally:
        ray.shutdown()
    assert reported == list(range(3))
    # Never three at once. Two overlap only where Ray starts their workers together, which a busy machine (the other
    # test worker building a tree) does not promise: there each trial may run alone.
    most = max(sum(a <= t < b for a, b in spans) for t, _ in spans)
    assert 1 <= most <= 2, spans


@pytest.mark.slow
def test_the_start_report_never_waits_on_the_queue(tmp_path):
    """Waiting (``ray.get``) is what lends a trial's CPU back: a report to a queue that cannot take it returns."""
    ray = pytest.importorskip("ray")
    from ray.util.queue import Queue

    from drem_maniskill.rl.sweep import report_start

    ray.init(num_cpus=1, include_dashboard=False, log_to_driver=False)
    try:
        queue = Queue(maxsize=1, actor_options={"num_cpus": 0})
        queue.put("first")  # full: a waiting put would never return
        t0 = time.time()
        report_start(queue, "second")
        assert time.time() - t0 < 5
        assert queue.get_nowait() == "first"
    finally:
        ray.shutdown()


def test_without_ray_the_error_names_the_extra(tmp_path, monkeypatch):
    monkeypatch.setitem(sys.modules, "ray", None)
    with pytest.raises(SystemExit, match=r"pip install drem-maniskill\[sweep\]"):
        main(["sweep", "--tasks", "PegInHole-v1", "--rewards", "sparse", "--seeds", "0", "--out", str(tmp_path),
              *TINY])


def test_a_folder_holding_another_run_stops_the_sweep_before_ray(tmp_path, monkeypatch):
    (config,) = plan_trials(["PegInHole-v1"], ["sparse"], [0], 200, tmp_path)
    _finished_run(RLConfig.from_dict({**config.to_dict(), "gamma": 0.5}), 100)
    monkeypatch.setitem(sys.modules, "ray", None)
    with pytest.raises(ValueError, match="holds a run with another config"):
        run_sweep([config], tmp_path)


# Two state-preset trials of 200 steps, checkpointed at 100: nothing renders, so the trials reach their first
# checkpoint in seconds and still have half their run ahead when the sweep is killed there.
KILLED = ["--steps", "200", "--eval-every", "100", "--eval-episodes", "1", "--learning-starts", "50",
          "--batch-size", "16"]


def _sweep(out: Path) -> list:
    return [sys.executable, "-m", "drem_maniskill.cli", "sweep", "--tasks", "PegInHole-v1", "--rewards", "sparse",
            "dense", "--seeds", "0", "--preset", "state", "--out", str(out), *KILLED]


def _wait_until_no_one_trains(run: Path, wait_s: float = 120) -> None:
    from drem_maniskill.rl.train_policy import run_lock

    if run.exists():
        with run_lock(run, wait_s=wait_s):
            pass


def _step(run: Path) -> int:
    latest = run / "checkpoints" / "latest.json"
    return json.loads(latest.read_text())["step"] if latest.exists() else 0


@pytest.mark.slow
def test_a_sweep_on_local_ray_killed_and_rerun_finishes_every_run(tmp_path, capsys):
    """Two trials on local Ray; the sweep is killed at the first checkpoint, rerun, then rerun once more (a no-op)."""
    out = tmp_path / "sweep"
    runs = {reward: out / "PegInHole-v1" / reward / "seed0" for reward in ("sparse", "dense")}
    with open(tmp_path / "first.log", "w") as log:
        proc = subprocess.Popen(_sweep(out), stdout=log, stderr=subprocess.STDOUT, start_new_session=True)
        deadline = time.time() + 300
        while proc.poll() is None and time.time() < deadline and not any(_step(r) for r in runs.values()):
            time.sleep(0.5)
        os.killpg(proc.pid, signal.SIGKILL)  # the sweep, Ray's processes and the trials
        proc.wait()
    for run in runs.values():  # a Ray worker can outlive the sweep by seconds and write on; wait until it ends
        _wait_until_no_one_trains(run)
    at_kill = {reward: _step(run) for reward, run in runs.items()}
    assert any(at_kill.values()), (tmp_path / "first.log").read_text()[-3000:]

    second = subprocess.run(_sweep(out), capture_output=True, text=True, timeout=600)
    assert second.returncode == 0, second.stdout[-3000:] + second.stderr[-3000:]
    for reward, run in runs.items():
        assert [r["steps"] for r in read_eval_csv(run / "eval.csv")] == [0, 100, 200]
        assert RLConfig.load(run / "config.json").reward == reward
        if 0 < at_kill[reward] < 200:  # resumed from the checkpoint it had
            assert f"start state PegInHole-v1 {reward} seed0 (from step {at_kill[reward]}" in second.stdout
            assert (run / "sb3" / f"from{at_kill[reward]}" / "progress.csv").exists()
        elif at_kill[reward] == 0:
            assert f"done state PegInHole-v1 {reward} seed0: success" in second.stdout
    assert 0 < min(v for v in at_kill.values() if v) < 200, at_kill  # the sweep was killed mid-run, not after it
    assert (out / "logs" / "state-PegInHole-v1-dense-seed0.log").exists()
    assert "failed" not in second.stdout.split("[sweep] summary")[-1].replace("0 failed", "")

    # Once more, in this process: every run is finished, so nothing starts Ray.
    assert main(_sweep(out)[3:]) == 0
    third = capsys.readouterr().out
    assert "0 done, 2 skipped, 0 failed" in third and "trials on Ray" not in third

    from drem_maniskill.rl.compare import compare_runs

    rows = compare_runs(list(runs.values()), str(tmp_path / "cmp"))["rows"]
    assert sorted(row["reward"].split(",")[0] for row in rows) == ["dense", "sparse"]
