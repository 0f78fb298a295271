"""get_policy: which policies exist where, and the errors that say so."""

from __future__ import annotations

import gymnasium as gym
import pytest

import drem_maniskill  # noqa: F401
from drem_maniskill.experts import get_policy
from drem_maniskill.experts.stock import PlugChargerExpert

STOCK = "PegInsertionSide-v1"


def test_no_scripted_expert_for_a_stock_task_is_a_clear_error():
    from drem_maniskill.experts import get_policy

    env = gym.make("PickCube-v1", obs_mode="state", control_mode="pd_ee_delta_pose")
    try:
        with pytest.raises(ValueError, match="no scripted expert for PickCube-v1.*PlugCharger-v1.*RecordEpisode"):
            get_policy("expert", env)
        action = get_policy("random", env, seed=1)(None)
        assert action.shape == (1, 7) and action.abs().max() <= 1
    finally:
        env.close()


def test_get_policy_gives_the_stock_expert_and_checks_the_control_mode():
    env = gym.make("PlugCharger-v1", obs_mode="state", control_mode="pd_ee_delta_pose")
    try:
        policy = get_policy("expert", env)
        assert isinstance(policy, PlugChargerExpert)
        obs, _ = env.reset(seed=0)
        action = policy(obs)
        assert action.shape == (1, 7) and action.abs().max() <= 1
    finally:
        env.close()
    env = gym.make("PegInsertionSide-v1", obs_mode="state", control_mode="pd_joint_delta_pos")
    try:
        with pytest.raises(ValueError, match="control_mode='pd_ee_delta_pose'.*pd_joint_delta_pos"):
            get_policy("expert", env)
    finally:
        env.close()
