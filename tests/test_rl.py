"""SAC runs (drem_maniskill.rl): tiny training, interrupt and resume, reward names, compare."""

from __future__ import annotations

import csv
import json

import pytest

from drem_maniskill.rl import REWARDS, RLConfig, reward_spec
from drem_maniskill.rl.compare import compare_runs, steps_to_reach
from drem_maniskill.rl.train_policy import EVAL_COLUMNS, latest_checkpoint, read_eval_csv


def _tiny(tmp_path, reward="dense", **kw) -> RLConfig:
    return RLConfig.preset("light", task="PegInHole-v1", reward=reward, seed=0, steps=64, learning_starts=16, batch_size=16,
                           eval_every=32, eval_episodes=2, threads=1, out=str(tmp_path / "run"), **kw)


def test_unknown_reward_is_a_clear_error(capsys):
    with pytest.raises(ValueError) as err:
        reward_spec("shaped")
    for name in REWARDS:
        assert name in str(err.value)
    assert "'shaped'" in str(err.value)
    from drem_maniskill.rl.__main__ import main

    assert main(["train-policy", "--reward", "shaped", "--steps", "8"]) == 2
    assert "unknown reward 'shaped'; choose one of: sparse, dense" in capsys.readouterr().err


def test_missing_image_only_checkpoint_names_the_file(tmp_path, monkeypatch):
    import drem_maniskill.drem.checkpoint as checkpoints

    monkeypatch.setattr(checkpoints, "default_checkpoint", lambda task, image_only=False: tmp_path / task / "drem_image.pt")
    with pytest.raises(FileNotFoundError, match=r"drem_image\.pt.*train-reward .*--modalities fixed wrist"):
        REWARDS["drem-image"].make("PegInHole-v1", {})


def test_paper_preset_gives_ft_only_to_drem():
    assert RLConfig.preset("paper", reward="drem").uses_ft
    assert not RLConfig.preset("paper", reward="drem-image").uses_ft
    assert RLConfig.preset("light", reward="sparse").uses_ft  # light: the same obs for every reward


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
    assert rows[("PegInHole-v1", "sparse")]["steps_to_50"] == "not reached"
    assert rows[("PegInHole-v1", "sparse")]["final_success"] == pytest.approx(0.2)
    assert rows[("USBInsertion-v1", "drem")]["steps_to_50"] == 1000
    assert "not reached" in open(result["markdown"]).read()


@pytest.mark.slow
def test_train_policy_tiny_writes_eval_csv_and_checkpoint(tmp_path):
    from drem_maniskill.rl.train_policy import train_policy

    result = train_policy(_tiny(tmp_path))
    run = tmp_path / "run"
    with (run / "eval.csv").open() as f:
        assert next(csv.reader(f)) == list(EVAL_COLUMNS)
    assert [r["steps"] for r in read_eval_csv(run / "eval.csv")] == [0, 32, 64]
    ckpt = latest_checkpoint(run)
    assert ckpt.name == "step_64" and (ckpt / "model.zip").exists() and (ckpt / "replay_buffer.pkl").exists()
    assert json.loads((ckpt / "progress.json").read_text())["num_timesteps"] == 64
    assert RLConfig.load(run / "config.json") == _tiny(tmp_path)
    assert list((run / "tb").glob("events.out.tfevents.*"))
    assert result["steps"] == 64 and result["resumed_from"] == 0


@pytest.mark.slow
def test_interrupted_run_resumes_from_its_checkpoint(tmp_path):
    """Interrupt after the step-32 checkpoint (VICE, so its state is checkpointed too); rerun continues from 32."""
    from stable_baselines3.common.callbacks import BaseCallback

    from drem_maniskill.rl.train_policy import train_policy

    class Interrupt(BaseCallback):
        def _on_step(self):
            if self.num_timesteps >= 40:
                raise KeyboardInterrupt
            return True

    config = _tiny(tmp_path, reward="vice",
                   reward_kwargs=dict(update_every=16, train_steps=2, batch_size=8, buffer_size=256, goal_seeds=1))
    with pytest.raises(KeyboardInterrupt):
        train_policy(config, callbacks=[Interrupt()])
    assert latest_checkpoint(tmp_path / "run").name == "step_32"
    assert (latest_checkpoint(tmp_path / "run") / "vice.pt").exists()
    result = train_policy(config)
    assert result["resumed_from"] == 32 and result["steps"] == 64
    assert [r["steps"] for r in read_eval_csv(tmp_path / "run" / "eval.csv")] == [0, 32, 64]
    assert (tmp_path / "run" / "sb3" / "from32" / "progress.csv").exists()


@pytest.mark.slow
def test_comparison_script_runs_every_reward_and_draws_the_curves(tmp_path):
    """scripts/sac_comparison.sh (the one command behind docs/results.md), at a tiny scale."""
    import os
    import subprocess
    import sys
    from pathlib import Path

    root = Path(__file__).resolve().parents[1]
    env = dict(os.environ, OUT=str(tmp_path), EVAL_EVERY="8", EVAL_EPISODES="1", LEARNING_STARTS="8",
               PATH=f"{Path(sys.executable).parent}:{os.environ['PATH']}")
    proc = subprocess.run(["bash", str(root / "scripts" / "sac_comparison.sh"), "PegInHole-v1", "16", "0", "sparse", "engineered"],
                          env=env, capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert "done sparse 0" in proc.stdout and "done engineered 0" in proc.stdout
    for reward in ("sparse", "engineered"):
        assert [r["steps"] for r in read_eval_csv(tmp_path / "PegInHole-v1" / reward / "seed0" / "eval.csv")] == [0, 8, 16]
    summary = json.loads((tmp_path / "comparison-PegInHole-v1" / "comparison.json").read_text())
    assert {row["reward"] for row in summary["rows"]} == {"sparse", "engineered"}
    assert (tmp_path / "comparison-PegInHole-v1" / "comparison.png").stat().st_size > 10_000


def test_sac_env_on_a_stock_task(tmp_path, monkeypatch):
    """PlugCharger-v1 (ManiSkill's, no F/T, sparse only): its two cameras and state; drem through the wrapper."""
    from pathlib import Path

    import torch

    import drem_maniskill.drem.checkpoint as checkpoints
    from drem_maniskill.rl.run_env import make_env
    from tests.test_aliases import tiny_stock_checkpoint

    ckpt = Path(tiny_stock_checkpoint(tmp_path / "drem.pt", env_id="PlugCharger-v1"))
    monkeypatch.setattr(checkpoints, "default_checkpoint", lambda task, image_only=False: ckpt if task == "PlugCharger-v1" else None)
    sparse = RLConfig.preset("light", task="PlugCharger-v1", reward="sparse")
    assert not sparse.uses_ft
    env, vice = make_env(sparse, for_eval=True)
    try:
        assert vice is None
        obs, _ = env.reset(seed=0)
        assert set(obs) == {"base_camera", "hand_camera", "state"}
        assert obs["base_camera"].shape == (1, 3, 32, 32) and obs["base_camera"].dtype == torch.uint8
        assert obs["state"].shape == (1, 9 + 7)  # qpos + tcp pose
        _, r, *_ = env.step(torch.zeros(1, 7))
        assert float(r[0]) == 0.0
    finally:
        env.close()
    env, _ = make_env(RLConfig.preset("light", task="PlugCharger-v1", reward="drem"), for_eval=True)
    try:
        env.reset(seed=0)
        _, r, _, _, info = env.step(torch.zeros(1, 7))
        assert float(info["original_reward"][0]) == 0.0 and float(r[0]) != 0.0
    finally:
        env.close()
    with pytest.raises(ValueError, match=r"PlugCharger-v1 the rewards are \['sparse', 'drem'\].*'engineered'"):
        make_env(RLConfig.preset("light", task="PlugCharger-v1", reward="engineered"))
