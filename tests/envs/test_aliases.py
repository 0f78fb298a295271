"""DREM-by-default env ids: our tasks' aliases and ``register_drem_env`` on a stock ManiSkill task."""

from __future__ import annotations

import gymnasium as gym
import pytest
import torch

import drem_maniskill  # noqa: F401  (registers the ids)
from drem_maniskill import register_drem_env
from drem_maniskill.envs.aliases import drem_env_id
from tests.conftest import tiny_stock_checkpoint

STOCK = "PegInsertionSide-v1"


def test_drem_env_id_puts_drem_before_the_version():
    assert drem_env_id("PegInsertionSide-v1") == "PegInsertionSide-DREM-v1"
    assert drem_env_id("Some-v2-Task-v10") == "Some-v2-Task-DREM-v10"
    assert drem_env_id("NoVersion") == "NoVersion-DREM"


def test_alias_defaults_to_drem_and_matches_the_task_with_reward_mode_drem():
    """The alias is the task with reward_mode="drem", paying R - 1 (safe under termination) unless drem_form="paper"."""
    alias = gym.make("PegInHole-DREM-v1")
    plain = gym.make("PegInHole-v1", reward_mode="drem")
    paper_alias = gym.make("PegInHole-DREM-v1", drem_form="paper")
    try:
        assert alias.unwrapped.reward_mode == "drem" and alias.unwrapped.env_id == "PegInHole-v1"
        assert alias.unwrapped.drem_form == "shifted" and plain.unwrapped.drem_form == "paper"
        assert alias.spec.max_episode_steps == plain.spec.max_episode_steps
        rewards, successes = [], []
        for env in (alias, plain, paper_alias):
            env.reset(seed=3)
            _, reward, _, _, info = env.step(torch.full((1, 6), 0.3))
            rewards.append(reward)
            successes.append(info["success"])
        torch.testing.assert_close(rewards[0], rewards[1] - 1.0)
        torch.testing.assert_close(rewards[2], rewards[1])
        assert float(rewards[0][0]) <= 0
        torch.testing.assert_close(successes[0], successes[1])
    finally:
        alias.close(), plain.close(), paper_alias.close()


def test_alias_keeps_the_other_reward_modes():
    sparse = gym.make("USBInsertion-DREM-v1", reward_mode="sparse")
    try:
        sparse.reset(seed=0)
        _, reward, *_ = sparse.step(torch.zeros(1, 6))
        assert sparse.unwrapped.reward_mode == "sparse" and float(reward[0]) == 0.0
    finally:
        sparse.close()


def test_alias_under_maniskill_vector_env():
    from mani_skill.vector.wrappers.gymnasium import ManiSkillVectorEnv

    env = ManiSkillVectorEnv(gym.make("PegInHole-DREM-v1", obs_mode="state"), auto_reset=True, ignore_terminations=True)
    try:
        assert env.unwrapped.reward_mode == "drem"
        env.reset(seed=0)
        _, reward, _, _, info = env.step(torch.zeros(1, 6))
        assert reward.shape == (1,) and -2.0 < float(reward[0]) < 1.5 and "success" in info
    finally:
        env.close()


def test_register_drem_env_on_a_stock_task(tmp_path):
    from mani_skill.vector.wrappers.gymnasium import ManiSkillVectorEnv

    from drem_maniskill.drem.wrapper import DREMRewardWrapper

    ckpt = tiny_stock_checkpoint(tmp_path / "drem.pt")
    env_id = register_drem_env(STOCK, ckpt, control_mode="pd_ee_delta_pose")
    assert env_id == "PegInsertionSide-DREM-v1"
    assert gym.spec(env_id).max_episode_steps == gym.spec(STOCK).max_episode_steps
    alias = ManiSkillVectorEnv(gym.make(env_id, obs_mode="state"), auto_reset=False, ignore_terminations=True)
    # The id pays R - 1 (drem_form "shifted"), as the wrapper does with form="shifted".
    dense = gym.make(STOCK, obs_mode="state", control_mode="pd_ee_delta_pose", reward_mode="dense")
    wrapped = DREMRewardWrapper(dense, ckpt, form="shifted")
    alias_dense = gym.make(env_id, obs_mode="state", reward_mode="dense")
    try:
        u = alias.unwrapped
        # The registration's kwargs are defaults of the new id; DREM is the default reward.
        assert u.reward_mode == "drem" and u.control_mode == "pd_ee_delta_pose"
        assert alias_dense.unwrapped.reward_mode == "dense"
        action = torch.tensor([[0.3, 0.0, -0.3, 0.0, 0.0, 0.0, 1.0]])
        for env in (alias, wrapped, alias_dense):
            env.reset(seed=2)
        for _ in range(2):
            _, r_alias, _, _, i_alias = alias.step(action)
            _, r_wrapped, _, _, i_wrapped = wrapped.step(action)
            _, r_dense, _, _, i_dense = alias_dense.step(action)
            # DREM through the id equals DREM through the wrapper; success is the task's own.
            torch.testing.assert_close(r_alias.float(), r_wrapped.float(), atol=1e-5, rtol=1e-5)
            assert torch.equal(i_alias["success"], i_wrapped["success"])
            assert torch.equal(i_dense["success"], i_wrapped["success"])
            # Other reward modes are the stock task's, untouched.
            torch.testing.assert_close(r_dense, i_wrapped["original_reward"])
            assert not torch.allclose(r_alias.float(), r_dense.float())
    finally:
        alias.close(), wrapped.close(), alias_dense.close()


def test_register_drem_env_rejects_what_does_not_fit(tmp_path):
    ckpt = tiny_stock_checkpoint(tmp_path / "drem.pt")
    with pytest.raises(ValueError, match="trained on 'PegInsertionSide-v1', not 'PlugCharger-v1'"):
        register_drem_env("PlugCharger-v1", ckpt)
    with pytest.raises(ValueError, match="not a registered ManiSkill env id"):
        register_drem_env("NoSuchTask-v1", ckpt)
    # A checkpoint that needs a camera the env lacks fails at gym.make, not at the first step.
    from drem_maniskill.drem.checkpoint import (
        CheckpointError,
        load_checkpoint,
        save_checkpoint,
    )

    header, weights = load_checkpoint(ckpt)
    bad_header = {**header, "camera_uids": ["base_camera", "no_such_camera"]}
    bad = save_checkpoint(str(tmp_path / "bad.pt"), bad_header, weights)
    env_id = register_drem_env(STOCK, bad, new_env_id="PegInsertionSide-BadDREM-v1")
    with pytest.raises(CheckpointError, match="no_such_camera"):
        gym.make(env_id, obs_mode="state")
