"""Scripted experts for ManiSkill's PegInsertionSide-v1 and PlugCharger-v1."""

from __future__ import annotations

import json

import gymnasium as gym
import numpy as np
import pytest
import torch

import drem_maniskill  # noqa: F401
from drem_maniskill.experts import get_policy, rollout, success_rate
from drem_maniskill.experts.stock import PegInsertionSideExpert


@pytest.mark.parametrize("env_id", ["PegInsertionSide-v1", "PlugCharger-v1"])
def test_stock_expert_solves_the_first_seeds(env_id):
    result = success_rate(env_id, "expert", seeds=range(3))
    assert result["success_rate"] == 1.0, result


def test_random_actions_do_not_solve_peg_insertion_side():
    """The contrast that makes the test above mean something: success is not a given."""
    env = gym.make("PegInsertionSide-v1", obs_mode="state", control_mode="pd_ee_delta_pose")
    try:
        assert not rollout(env, get_policy("random", env, seed=0), seed=0, steps=60).success
    finally:
        env.close()


def test_stock_expert_restarts_at_each_reset():
    """One policy object over two episodes of the same seed gives the same actions: its phase resets."""
    env = gym.make("PegInsertionSide-v1", obs_mode="state", control_mode="pd_ee_delta_pose")
    try:
        policy = get_policy("expert", env)
        assert isinstance(policy, PegInsertionSideExpert)
        runs = []
        for _ in range(2):
            obs, _ = env.reset(seed=3)
            actions = []
            for _ in range(25):  # past the grasp: the phase has moved on by then
                actions.append(policy(obs))
                obs, *_ = env.step(actions[-1])
            runs.append(torch.cat(actions))
        assert int(policy.phase.max()) >= 3
        torch.testing.assert_close(runs[0], runs[1], atol=1e-5, rtol=0)
    finally:
        env.close()


@pytest.mark.parametrize("env_id", ["PegInsertionSide-v1", "PlugCharger-v1"])
def test_shipped_stock_checkpoint_rises_along_an_expert_episode(env_id):
    """rewards/<task>/drem.pt (image-only, the task's two cameras) on held-out seed 0."""
    from scipy.stats import spearmanr

    from drem_maniskill.drem.reward import default_checkpoint
    from drem_maniskill.drem.wrapper import DREMRewardWrapper

    path = default_checkpoint(env_id)
    env = DREMRewardWrapper(gym.make(env_id, obs_mode="state", control_mode="pd_ee_delta_pose"), str(path))
    try:
        assert env.reward_model.header["env_id"] == env_id
        assert env.reward_model.header["modalities"] == ["fixed", "wrist"]
        ep = rollout(env, get_policy("expert", env), seed=0, steps=150)
        rewards = ep.rewards
        assert ep.success
        assert rewards[0] < 0.5 < rewards[-1]
        assert spearmanr(np.arange(len(rewards)), rewards).correlation > 0.8
    finally:
        env.close()


def test_scripted_success_command_on_a_stock_task(capsys):
    """`drem-maniskill scripted-success` picks the end-effector controller the stock expert needs."""
    from drem_maniskill.cli import main

    assert main(["scripted-success", "--task", "PegInsertionSide-v1", "--episodes", "2"]) == 0
    out = capsys.readouterr().out
    result = json.loads(out[out.index("{"):])
    assert result["env_id"] == "PegInsertionSide-v1" and result["episodes"] == 2 and result["success_rate"] == 1.0
