"""Scripted experts for ManiSkill's PushCube-v1 and StackCube-v1."""

from __future__ import annotations

import gymnasium as gym
import pytest
import torch

import drem_maniskill  # noqa: F401
from drem_maniskill.experts import get_policy, rollout, success_rate
from drem_maniskill.experts.stock import STOCK_EXPERTS
from drem_maniskill.experts.stock_tabletop import PushCubeExpert, StackCubeExpert

TASKS = {"PushCube-v1": PushCubeExpert, "StackCube-v1": StackCubeExpert}


@pytest.mark.parametrize("env_id", sorted(TASKS))
def test_tabletop_expert_solves_the_first_seeds(env_id):
    assert STOCK_EXPERTS[env_id] is TASKS[env_id]
    result = success_rate(env_id, "expert", seeds=range(3))
    assert result["success_rate"] == 1.0, result
    assert result["horizon"] == 50


@pytest.mark.parametrize("env_id", sorted(TASKS))
def test_random_actions_do_not_solve_a_tabletop_task(env_id):
    """The contrast that makes the test above mean something: success is not a given."""
    env = gym.make(env_id, obs_mode="state", control_mode="pd_ee_delta_pose")
    try:
        assert not rollout(env, get_policy("random", env, seed=0), seed=0, steps=50).success
    finally:
        env.close()


@pytest.mark.parametrize("env_id, steps, phase", [("PushCube-v1", 10, 2), ("StackCube-v1", 25, 4)])
def test_tabletop_expert_restarts_at_each_reset(env_id, steps, phase):
    """One policy object over two episodes of the same seed gives the same actions: its phase resets."""
    env = gym.make(env_id, obs_mode="state", control_mode="pd_ee_delta_pose")
    try:
        policy = get_policy("expert", env)
        assert isinstance(policy, TASKS[env_id])
        runs = []
        for _ in range(2):
            obs, _ = env.reset(seed=1)
            actions = []
            for _ in range(steps):  # into the last phases: the phase has moved on by then
                actions.append(policy(obs))
                obs, *_ = env.step(actions[-1])
            runs.append(torch.cat(actions))
        assert int(policy.phase.max()) >= phase
        torch.testing.assert_close(runs[0], runs[1], atol=1e-5, rtol=0)
    finally:
        env.close()


@pytest.mark.slow
def test_the_noisy_pushcube_expert_fails_on_some_seeds_and_succeeds_on_others():
    """The examination's expert-and-noisy AUROC needs both: at N(0, 0.1) the push never fails, at 0.3 it does."""
    env = gym.make("PushCube-v1", obs_mode="state", control_mode="pd_ee_delta_pose")
    try:
        def solved(policy):
            return [bool(rollout(env, policy, seed=s, steps=50).success) for s in range(8)]

        noisy = solved(get_policy("noisy_expert", env, seed=0))
        assert any(noisy) and not all(noisy), noisy
        assert all(solved(STOCK_EXPERTS["PushCube-v1"](env, seed=0, action_noise=0.1)))
    finally:
        env.close()
