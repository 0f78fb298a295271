"""The engineered baseline: the paper's -exp(kappa d), as a reward mode of our tasks."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from drem_maniskill.baselines import DEFAULT_KAPPA, engineered_reward, pose_distance
from drem_maniskill.experts import get_policy, rollout
from tests.conftest import TASKS, make_env

CAMS = ("fixed_camera", "wrist_camera")


def test_engineered_formula():
    d = torch.tensor([0.0, 0.05, 0.1])
    r = engineered_reward(d, kappa=10.0)
    assert torch.allclose(r, -torch.exp(10.0 * d))
    assert float(r[0]) == -1.0 and bool((r[1:] < r[:-1]).all())
    goal = torch.tensor([[0.0, 0.0, -0.04]])
    pos = torch.tensor([[0.03, 0.0, -0.04], [0.0, 0.0, -0.04]])
    dist = pose_distance(pos, goal, torch.tensor([0.0, 0.2]), rot_weight=0.1)
    assert torch.allclose(dist, torch.tensor([0.03, 0.02]))


@pytest.mark.parametrize("task", TASKS)
def test_engineered_reward_grows_towards_the_inserted_pose(task):
    env = make_env(task, obs_mode="state", reward_mode="engineered")
    assert env.unwrapped.engineered_kappa == DEFAULT_KAPPA
    ep = rollout(env, get_policy("expert", env), seed=0)
    rewards = ep.rewards
    assert ep.success and bool(ep.info["success"].all())
    assert rewards[-1] > rewards[0]
    assert all(r <= -1.0 for r in rewards)  # -1 only at the fully-inserted pose
    u = env.unwrapped
    # Recompute from the env's evaluation: the formula, with d to the bottom of the hole.
    info = u.evaluate()
    goal = torch.tensor([[0.0, 0.0, -u.hole_depth]])
    d = pose_distance(info["tip_in_socket"], goal, torch.sqrt(info["tilt_error"] ** 2 + info["yaw_error"] ** 2))
    r = u.compute_engineered_reward(obs=None, action=None, info=info)
    assert torch.allclose(r, -torch.exp(DEFAULT_KAPPA * d))
    # At the goal itself the reward is exactly its maximum.
    at_goal = dict(info, tip_in_socket=goal.clone(), tilt_error=torch.zeros(1), yaw_error=torch.zeros(1))
    assert float(u.compute_engineered_reward(obs=None, action=None, info=at_goal)[0]) == -1.0


def test_engineered_kappa_is_an_env_kwarg():
    task = TASKS[0]
    a = make_env(task, obs_mode="state", reward_mode="engineered")
    b = make_env(task, obs_mode="state", reward_mode="engineered", engineered_kappa=20.0)
    ra = rollout(a, get_policy("expert", a), seed=3).rewards
    rb = rollout(b, get_policy("expert", b), seed=3).rewards
    # -exp(20 d) = -(exp(10 d))^2: the same distances, the reward squared in magnitude.
    assert np.allclose(rb[0], -(ra[0] ** 2), rtol=1e-3)
    assert rb[0] < ra[0]
