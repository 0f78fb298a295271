"""DREMRewardWrapper: the reward replaced, the original kept in info."""

from __future__ import annotations

import gymnasium as gym
import pytest
import torch


@pytest.mark.slow
def test_wrapper_replaces_the_reward_and_keeps_the_original(pipeline):
    from drem_maniskill.drem.wrapper import DREMRewardWrapper

    inner = gym.make("PegInHole-v1", obs_mode="state", reward_mode="normalized_dense")
    reference = gym.make("PegInHole-v1", obs_mode="rgb", reward_mode="drem", drem_checkpoint=pipeline["checkpoint"])
    env = DREMRewardWrapper(inner, pipeline["checkpoint"])
    try:
        env.reset(seed=9)
        reference.reset(seed=9)
        action = torch.tensor([[0.2, -0.1, -0.4, 0.0, 0.0, 0.1]])
        _, reward, _, _, info = env.step(action)
        _, expected, _, _, _ = reference.step(action)
        torch.testing.assert_close(reward, expected, atol=1e-4, rtol=0)
        assert 0 < info["original_reward"].item() <= 1  # the task's normalized_dense
    finally:
        env.close()
        reference.close()
