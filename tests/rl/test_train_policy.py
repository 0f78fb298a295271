"""train-policy: a tiny run, its files, interruption and resume (VICE included)."""

from __future__ import annotations

import csv
import json
import os
import signal
import subprocess
import sys

import pytest

from drem_maniskill.rl import RLConfig
from drem_maniskill.rl.train_policy import (
    EVAL_COLUMNS,
    latest_checkpoint,
    read_eval_csv,
)


def _tiny(tmp_path, reward="dense", **kw) -> RLConfig:
    return RLConfig.from_preset("light", task="PegInHole-v1", reward=reward, seed=0, steps=64, learning_starts=16,
                                batch_size=16, eval_every=32, eval_episodes=2, threads=1, out=str(tmp_path / "run"),
                                **kw)


@pytest.mark.slow
def test_train_policy_tiny_writes_eval_csv_and_checkpoint(tmp_path, monkeypatch):
    from drem_maniskill.rl import train_policy as tp

    # The rate read at each evaluation, from the model SB3 trains (its episode buffer set up from step 0 on).
    monkeypatch.setattr(tp, "training_success_rate", lambda model: len(model.ep_success_buffer) + 0.25)
    result = tp.train_policy(_tiny(tmp_path))
    run = tmp_path / "run"
    with (run / "eval.csv").open() as f:
        assert next(csv.reader(f)) == list(EVAL_COLUMNS)
    rows = read_eval_csv(run / "eval.csv")
    assert [r["steps"] for r in rows] == [0, 32, 64]
    # One env, 50-step episodes: the first training episode has ended by step 64, none by 32.
    assert [r["train_success_rate"] for r in rows] == [0.25, 0.25, 1.25]
    ckpt = latest_checkpoint(run)
    assert ckpt.name == "step_64" and (ckpt / "model.zip").exists() and (ckpt / "replay_buffer.pkl").exists()
    assert json.loads((ckpt / "progress.json").read_text())["num_timesteps"] == 64
    assert RLConfig.load(run / "config.json") == _tiny(tmp_path)
    assert list((run / "tb").glob("events.out.tfevents.*"))
    assert result["steps"] == 64 and result["resumed_from"] == 0


def test_training_success_rate_is_sb3s_over_its_finished_episodes():
    from collections import deque
    from types import SimpleNamespace

    from drem_maniskill.rl.train_policy import training_success_rate

    assert training_success_rate(SimpleNamespace(ep_success_buffer=deque([True, False, False, True]))) == 0.5
    assert training_success_rate(SimpleNamespace(ep_success_buffer=deque())) == 0.0
    assert training_success_rate(SimpleNamespace(ep_success_buffer=None)) == 0.0  # before learn() sets it up


def test_an_eval_csv_without_the_training_success_column_is_read_and_extended(tmp_path):
    """A run written before the column resumes: its rows keep a blank, the rows after it carry the rate."""
    from drem_maniskill.rl.train_policy import _write_eval_csv

    path = tmp_path / "eval.csv"
    path.write_text("steps,success_rate,mean_return,wall_time\n0,0.0,-50.0,10.0\n2500,0.1,-40.0,90.5\n")
    rows = read_eval_csv(path)
    assert rows[1] == dict(steps=2500, success_rate=0.1, mean_return=-40.0, wall_time=90.5)
    rows.append(dict(steps=5000, success_rate=0.2, mean_return=-30.0, wall_time=180.0, train_success_rate=0.03))
    _write_eval_csv(path, rows)
    with path.open() as f:
        assert next(csv.reader(f)) == list(EVAL_COLUMNS)
    again = read_eval_csv(path)
    assert "train_success_rate" not in again[0] and again[2]["train_success_rate"] == 0.03
    assert again[:2] == rows[:2]


def test_a_run_another_process_is_training_waits_for_it_then_fails_without_touching_the_run(tmp_path, monkeypatch):
    """A rerun while the killed sweep's trial still writes the folder must not write beside it."""
    from drem_maniskill.rl import train_policy as tp

    config = _tiny(tmp_path)
    config.run_dir.mkdir(parents=True)
    holder = subprocess.Popen([sys.executable, "-c", (
        "import time; from drem_maniskill.rl.train_policy import run_lock\n"
        f"with run_lock({str(config.run_dir)!r}):\n    print('held', flush=True); time.sleep(60)")],
        stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout.readline().strip() == "held"
        monkeypatch.setattr(tp, "LOCK_WAIT_S", 0.5)
        with pytest.raises(RuntimeError, match=rf"being trained by another process \(pid {holder.pid}\); stop"):
            tp.train_policy(config)
        assert sorted(p.name for p in config.run_dir.iterdir()) == [".lock"]  # no config.json, no eval.csv
    finally:
        holder.send_signal(signal.SIGKILL)
        holder.wait()
    with tp.run_lock(config.run_dir, wait_s=0):  # a killed holder leaves no lock behind
        assert (config.run_dir / ".lock").read_text() == str(os.getpid())


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


def test_a_run_resumed_late_gets_a_seed_numpy_accepts():
    """Resuming at 30,000 steps once asked numpy for seed 3e10 and failed; each resume point still gets its own seed."""
    import numpy as np

    from drem_maniskill.rl.train_policy import resume_seed

    seeds = [resume_seed(s, steps) for s in (0, 2) for steps in (32, 2_500, 30_000, 150_000)]
    for seed in seeds:
        np.random.default_rng(seed)
        assert 0 <= seed < 2**32
    assert len(set(seeds)) == len(seeds)


def test_resume_compares_the_drem_form_as_the_run_pays_it():
    """A run resumes under the same settings however the form was spelled; another form or gamma is refused."""
    import pytest

    from drem_maniskill.rl.config import RLConfig
    from drem_maniskill.rl.train_policy import _check_resumable

    saved = RLConfig.from_preset("state", reward="engineered", drem_form="paper")
    # The form means nothing here.
    _check_resumable(saved, RLConfig.from_preset("state", reward="engineered", steps=80_000))
    drem = RLConfig.from_preset("state", reward="drem", drem_form="shifted")
    _check_resumable(drem, RLConfig.from_preset("state", reward="drem"))  # unset: shifted, as episodes end at success
    with pytest.raises(ValueError, match="drem_form: saved 'shifted', now 'paper'"):
        _check_resumable(drem, RLConfig.from_preset("state", reward="drem", drem_form="paper"))
    with pytest.raises(ValueError, match="gamma: saved 0.95, now 0.9"):
        _check_resumable(saved, RLConfig.from_preset("state", reward="engineered", gamma=0.9))


def test_a_run_pins_its_drem_checkpoint_and_refuses_to_resume_on_another(tmp_path):
    """The run dir records the checkpoint's sha256; a retrained file under the same path stops a resume."""
    import shutil

    from drem_maniskill.rl.train_policy import file_sha256, pin_reward_checkpoint
    from tests.conftest import tiny_checkpoint

    ckpt = tmp_path / "drem.pt"
    shutil.copy(tiny_checkpoint(tmp_path / "a", "PegInHole-v1"), ckpt)
    run = tmp_path / "run"
    run.mkdir()
    config = RLConfig.from_preset("state", task="PegInHole-v1", reward="drem", reward_checkpoint=str(ckpt),
                                  out=str(run))
    pinned = pin_reward_checkpoint(config, run, resuming=False)
    assert pinned == dict(path=str(ckpt), sha256=file_sha256(ckpt))
    assert json.loads((run / "reward_checkpoint.json").read_text()) == pinned
    assert pin_reward_checkpoint(config, run, resuming=True) == pinned  # same file: resumes

    shutil.copy(tiny_checkpoint(tmp_path / "b", "PegInHole-v1", modalities=("fixed", "wrist")), ckpt)  # "retrained"
    with pytest.raises(ValueError, match=r"was trained on the reward checkpoint .*drem\.pt .*another file"):
        pin_reward_checkpoint(config, run, resuming=True)
    assert pin_reward_checkpoint(config, run, resuming=False)["sha256"] == file_sha256(ckpt)  # a fresh run re-pins

    engineered = RLConfig.from_preset("state", task="PegInHole-v1", reward="engineered", out=str(tmp_path / "eng"))
    (tmp_path / "eng").mkdir()
    assert pin_reward_checkpoint(engineered, tmp_path / "eng", resuming=False) is None
    assert not (tmp_path / "eng" / "reward_checkpoint.json").exists()


def test_each_drem_reward_names_the_checkpoint_it_reads():
    """drem and drem-guarded read drem.pt, drem-image reads drem_image.pt, --reward-checkpoint replaces both."""
    from drem_maniskill.rl.rewards import reward_checkpoint

    assert reward_checkpoint("drem", "PegInHole-v1").name == "drem.pt"
    assert reward_checkpoint("drem-guarded", "PegInHole-v1").name == "drem.pt"
    assert reward_checkpoint("drem-image", "USBInsertion-v1").name == "drem_image.pt"
    assert reward_checkpoint("drem-image", "USBInsertion-v1").parent.name == "USBInsertion-v1"
    assert str(reward_checkpoint("drem", "PegInHole-v1", "x/my.pt")) == "x/my.pt"
    assert reward_checkpoint("vice", "PegInHole-v1") is None and reward_checkpoint("sparse", "PegInHole-v1") is None


@pytest.mark.slow
def test_train_freq_sets_the_update_ratio_and_bf16_runs_the_gradient_step_in_bfloat16(tmp_path):
    """The speed settings of docs/rl.md: SB3 updates every ``train_freq`` steps (the presets: every step);
    ``train_bf16`` computes the step's layers in bfloat16 while the parameters stay float32."""
    import torch

    from drem_maniskill.rl.algos import algo_spec
    from drem_maniskill.rl.run_env import make_env
    from drem_maniskill.rl.vec_env import ManiSkillDictVecEnv
    from drem_maniskill.utils.episodes import max_episode_steps

    updates, dtypes = {}, {}
    for name, overrides in dict(preset={}, quarter=dict(train_freq=4, train_bf16=True)).items():
        config = RLConfig.from_preset("light", task="PegInHole-v1", reward="engineered", steps=48, learning_starts=16,
                                      batch_size=8, threads=1, out=str(tmp_path / name), **overrides)
        env, _ = make_env(config)
        venv = ManiSkillDictVecEnv(env, max_episode_steps(config.task))
        try:
            model = algo_spec(config.algo).build(config, venv)
            seen = set()
            layer = model.critic.q_networks[0][0]
            hook = layer.register_forward_hook(
                lambda m, i, out: seen.add(out.dtype) if torch.is_grad_enabled() else None
            )
            model.learn(total_timesteps=48)
            hook.remove()
            updates[name], dtypes[name] = model._n_updates, seen
            assert layer.weight.dtype == torch.float32
        finally:
            venv.close()
    # 32 env steps after learning starts: 32 updates at the preset's one per step, 8 at a quarter.
    assert updates == dict(preset=32, quarter=8)
    assert dtypes == dict(preset={torch.float32}, quarter={torch.bfloat16})


@pytest.mark.slow
def test_an_overlapped_run_steps_its_env_in_a_child_process_closes_it_and_resumes(tmp_path):
    """``overlap_env``: the run's env in a child process (closed when the run stops, interrupted or not), the
    gradient steps made while it steps; a rerun resumes from the checkpoint. VICE, which learns in this process,
    stays here."""
    import multiprocessing

    from stable_baselines3.common.callbacks import BaseCallback

    from drem_maniskill.rl.train_policy import train_policy

    seen = {}

    class Interrupt(BaseCallback):
        def _on_step(self):
            seen["children"] = [p.name for p in multiprocessing.active_children()]
            seen["deferred"] = self.model._deferred
            if self.num_timesteps >= 40:
                raise KeyboardInterrupt
            return True

    config = RLConfig.from_preset("state", task="PegInHole-v1", reward="engineered", steps=64, learning_starts=16,
                                  batch_size=16, eval_every=32, eval_episodes=2, overlap_env=True,
                                  out=str(tmp_path / "run"))
    vice = RLConfig.from_preset("state", reward="vice", overlap_env=True)
    assert config.overlap_env_used and not vice.overlap_env_used
    with pytest.raises(KeyboardInterrupt):
        train_policy(config, callbacks=[Interrupt()])
    assert len(seen["children"]) == 1 and seen["deferred"] is not None
    assert multiprocessing.active_children() == []
    assert latest_checkpoint(tmp_path / "run").name == "step_32"
    result = train_policy(config)
    assert result["resumed_from"] == 32 and result["steps"] == 64 and result["env_time"] > 0
    assert [r["steps"] for r in read_eval_csv(tmp_path / "run" / "eval.csv")] == [0, 32, 64]
    assert multiprocessing.active_children() == []
