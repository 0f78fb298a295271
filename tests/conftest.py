"""Shared fixtures: one env per task and obs mode per test session (creating one costs seconds)."""

from __future__ import annotations

import gymnasium as gym
import pytest
import torch

import drem_maniskill  # noqa: F401  (registers the tasks)
from drem_maniskill.scripted import get_policy

TASKS = ("PegInHole-v1", "USBInsertion-v1")
_cache: dict = {}


def make_env(task: str, **kwargs):
    """A cached env; tests must reset it themselves."""
    key = (task, tuple(sorted(kwargs.items())))
    if key not in _cache:
        _cache[key] = gym.make(task, **kwargs)
    return _cache[key]


@pytest.fixture(scope="session", autouse=True)
def _close_envs():
    yield
    for env in _cache.values():
        env.close()
    _cache.clear()


def run_policy(env, name: str, seed: int, steps: int = 50, stop_on_success: bool = True, policy_seed: int = 0):
    """Run a scripted policy for one episode; returns the last (obs, info) and the step count."""
    policy = get_policy(name, env, seed=policy_seed)
    obs, info = env.reset(seed=seed)
    for t in range(steps):
        obs, _, terminated, truncated, info = env.step(policy(obs))
        if stop_on_success and bool(info["success"].any()):
            break
        if bool(truncated.any()):
            break
    return obs, info, t + 1


def hand_to_part(env) -> "torch.Tensor":
    """Raw pose ``[B, 7]`` of the part in the hand frame."""
    u = env.unwrapped
    return (u.agent.robot.links_map["panda_hand"].pose.inv() * u.part.pose).raw_pose
