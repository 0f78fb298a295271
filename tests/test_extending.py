"""docs/architecture.md's "how to add a task, a reward, an algorithm", each walked through once.

Each test does what the docs say, in the place the docs name, and then uses the new thing
through the package's ordinary entry points.
"""

from __future__ import annotations

import textwrap

import gymnasium as gym
import pytest
import torch
from stable_baselines3 import TD3

import drem_maniskill.drem.checkpoint as checkpoints
import drem_maniskill.envs as envs
from drem_maniskill.experts import get_policy, rollout
from drem_maniskill.rl import RLConfig
from drem_maniskill.rl.algos import ALGOS, AlgoSpec, algo_spec, policy_kwargs
from drem_maniskill.rl.rewards import REWARDS, RewardSpec, env_reward_mode, reward_spec
from drem_maniskill.rl.run_env import make_env
from tests.conftest import tiny_checkpoint

NEW_TASK = "WidePegInHole-v1"
TASK_FILE = '''
from mani_skill.utils.registration import register_env

from drem_maniskill.envs.peg_in_hole import PegInHoleEnv


@register_env("WidePegInHole-v1", max_episode_steps=50)
class WidePegInHoleEnv(PegInHoleEnv):
    """PegInHole-v1 with a 4 mm clearance."""

    env_id = "WidePegInHole-v1"
    default_clearance = 0.004
'''


@pytest.fixture(scope="module")
def new_task(tmp_path_factory):
    """Steps 1 and 2 of adding a task: its task file, and its line in the task list."""
    folder = tmp_path_factory.mktemp("envs")
    (folder / "wide_peg_in_hole.py").write_text(textwrap.dedent(TASK_FILE))
    # The task file sits in drem_maniskill/envs/ in a real addition; here a second folder of the package.
    envs.__path__.append(str(folder))
    try:
        yield envs.load_tasks({NEW_TASK: "wide_peg_in_hole"})
    finally:
        envs.__path__.remove(str(folder))


def test_adding_a_task(new_task, tmp_path, monkeypatch):
    assert new_task == {"WidePegInHole-DREM-v1": NEW_TASK}
    assert envs.is_insertion_task(NEW_TASK)
    monkeypatch.setattr(envs, "TASKS", envs.TASKS + (NEW_TASK,))
    from drem_maniskill.cli import build_parser

    assert NEW_TASK in build_parser().parse_args(["demo"]).tasks  # the demo's default tasks come from the list

    # Step 3, its data: without rewards/<id>/drem.pt the drem mode names the missing file ...
    monkeypatch.setattr(checkpoints, "REWARDS_DIRS", (tmp_path / "rewards",))
    missing = r"no DREM checkpoint ships for WidePegInHole-v1.*train-reward"
    with pytest.raises(checkpoints.CheckpointError, match=missing):
        gym.make(NEW_TASK, reward_mode="drem")
    # ... and with it, the alias rewards with it by default.
    tiny_checkpoint(tmp_path / "rewards" / NEW_TASK / "drem.pt", NEW_TASK)
    env = gym.make("WidePegInHole-DREM-v1", obs_mode="state")
    try:
        assert env.unwrapped.clearance == 0.004
        ep = rollout(env, get_policy("expert", env), seed=0)  # the scripted policies read it through InsertionEnv
        assert ep.success and all(-10 < r < 10 for r in ep.rewards) and len(set(ep.rewards)) > 1
    finally:
        env.close()
    assert all(spec.supports(NEW_TASK) for spec in REWARDS.values())
    env, _ = make_env(RLConfig.from_preset("light", task=NEW_TASK, reward="drem"), for_eval=True)
    try:
        obs, _ = env.reset(seed=1)
        assert set(obs) == {"fixed_camera", "wrist_camera", "ft", "state"}
    finally:
        env.close()


def test_adding_a_reward(monkeypatch):
    spec = RewardSpec("the task's staged dense reward, 0-6", env_reward_mode("dense"))
    monkeypatch.setitem(REWARDS, "dense-raw", spec)
    assert reward_spec("dense-raw").supports("PegInHole-v1") and not reward_spec("dense-raw").supports("PlugCharger-v1")
    env, learned = make_env(RLConfig.from_preset("light", task="PegInHole-v1", reward="dense-raw"), for_eval=True)
    try:
        assert learned is None and env.unwrapped.reward_mode == "dense"
        obs, _ = env.reset(seed=2)
        obs, reward, _, _, info = env.step(torch.zeros(1, 6))
        u = env.unwrapped
        assert float(reward[0]) == pytest.approx(float(u.compute_dense_reward(obs=None, action=None, info=info)[0]))
    finally:
        env.close()


def build_td3(config, venv):
    """The docs' TD3 builder."""
    return TD3("MultiInputPolicy", venv, learning_rate=config.learning_rate,
               buffer_size=min(config.buffer_size, config.steps),
               batch_size=config.batch_size, learning_starts=config.learning_starts, gamma=config.gamma,
               seed=config.seed, device=config.device, policy_kwargs=policy_kwargs(config))


def test_adding_an_algorithm(tmp_path, monkeypatch):
    from drem_maniskill.rl.train_policy import (
        latest_checkpoint,
        read_eval_csv,
        train_policy,
    )

    with pytest.raises(ValueError, match="unknown algorithm 'td3'; choose one of: sac"):
        algo_spec("td3")
    monkeypatch.setitem(ALGOS, "td3", AlgoSpec(TD3, build_td3))
    config = RLConfig.from_preset("light", task="PegInHole-v1", reward="sparse", algo="td3", steps=24,
                                  learning_starts=8, batch_size=8, eval_every=12, eval_episodes=1, threads=1,
                                  out=str(tmp_path / "run"), env_kwargs=dict(max_episode_steps=6))
    # TD3 cannot defer its gradient step into the env's (no train_while_env_steps): its env stays in this process.
    assert config.overlap_env and not config.overlap_env_used
    result = train_policy(config)
    assert result["steps"] == 24
    ckpt = latest_checkpoint(tmp_path / "run")
    assert (ckpt / "model.zip").exists() and (ckpt / "replay_buffer.pkl").exists()
    assert TD3.load(ckpt / "model.zip").num_timesteps == 24
    # Resumes as a TD3, from its checkpoint.
    config.steps = 36
    result = train_policy(config)
    assert result["resumed_from"] == 24 and result["steps"] == 36
    assert [r["steps"] for r in read_eval_csv(tmp_path / "run" / "eval.csv")] == [0, 12, 24, 36]
