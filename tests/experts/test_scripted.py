"""The scripted policies of our tasks."""

from __future__ import annotations

import pytest

from tests.conftest import TASKS, make_env, run_policy


@pytest.mark.parametrize("task", TASKS)
def test_expert_succeeds_on_a_few_seeds(task):
    env = make_env(task, obs_mode="state_dict")
    wins = sum(run_policy(env, "expert", seed=100 + s)[1]["success"].item() for s in range(5))
    assert wins >= 5 - (1 if task == "USBInsertion-v1" else 0)


def _hold_path(env, target, via, seed: int = 0, steps: int = 20):
    import numpy as np

    from drem_maniskill.experts.scripted import HoldPolicy

    obs, _ = env.reset(seed=seed)
    pi, path = HoldPolicy(env, target, via=via), []
    for _ in range(steps):
        obs, *_ = env.step(pi(obs))
        path.append(env.unwrapped.tip_pose_in_socket().p[0].cpu().numpy())
    return np.array(path)


def test_a_hold_through_a_via_point_goes_straight_down_beside_the_block():
    from drem_maniskill.pipeline.examine import SIDE_POSITION, hold_targets, hold_vias

    env = make_env("USBInsertion-v1", obs_mode="state_dict")
    target, via = hold_targets(env)[SIDE_POSITION], hold_vias(env)[SIDE_POSITION]
    side = env.unwrapped.side_contact
    path = _hold_path(env, target, via)
    assert abs(path[-1] - target).max() < 5e-4  # reached: 2 mm beside the block, 12 mm down
    low = path[:, 2] < 0.001
    assert low.any() and (path[low, 0] < -(side + 0.001)).all()  # never over the block below its top face
    assert (abs(path[low, 0] - target[0]) < 5e-4).all()  # straight down from the via point
