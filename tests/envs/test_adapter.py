"""The sampler's view of an env (envs.adapter): states of a stock task that replay a step."""

from __future__ import annotations

import gymnasium as gym
import torch

import drem_maniskill  # noqa: F401
from drem_maniskill.envs.adapter import adapter_for

STOCK = "PegInsertionSide-v1"


def test_stock_states_replay_a_step_through_the_adapter():
    """ManiSkill's set_state_dict leaves the PD drive targets stale; the adapter restores them."""
    env = gym.make(STOCK, obs_mode="state", control_mode="pd_ee_delta_pose")
    try:
        env.reset(seed=0)
        adapter = adapter_for(env)
        action = torch.tensor([[0.5, -0.3, 0.2, 0.0, 0.0, 0.1, -1.0]])
        env.step(action)  # moves the drive targets away from the reset pose
        saved = adapter.get_state()
        flat = adapter.flatten(saved)
        first, *_ = env.step(action)
        for _ in range(3):
            env.step(-action)
        adapter.set_state(adapter.unflatten(flat))
        again, *_ = env.step(action)
        assert torch.allclose(first, again, atol=1e-5)
        assert adapter.camera_map == {"fixed": "base_camera", "wrist": "hand_camera"} and not adapter.has_ft
        assert adapter.ee_state().shape == (1, 8)
    finally:
        env.close()
