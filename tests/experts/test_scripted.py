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
    from drem_maniskill.evaluate.probes import SIDE_POSITION, hold_targets, hold_vias

    env = make_env("USBInsertion-v1", obs_mode="state_dict")
    target, via = hold_targets(env)[SIDE_POSITION], hold_vias(env)[SIDE_POSITION]
    side = env.unwrapped.side_contact
    path = _hold_path(env, target, via)
    assert abs(path[-1] - target).max() < 5e-4  # reached: 2 mm beside the block, 12 mm down
    low = path[:, 2] < 0.001
    assert low.any() and (path[low, 0] < -(side + 0.001)).all()  # never over the block below its top face
    assert (abs(path[low, 0] - target[0]) < 5e-4).all()  # straight down from the via point



def test_a_hold_pushed_against_the_blocks_side_presses_it_sideways_and_down_where_the_overmould_meets_its_edge():
    from drem_maniskill.evaluate.probes import SIDE_DOWN, SIDE_PUSHED, hold_targets, hold_vias

    env = make_env("USBInsertion-v1", obs_mode="state_dict")
    target, via = hold_targets(env)[SIDE_PUSHED], hold_vias(env)[SIDE_PUSHED]
    side = env.unwrapped.side_contact
    path = _hold_path(env, target, via)
    assert abs(path[-1, 0] + side) < 5e-4  # the shell against the block's side, not through it
    assert abs(path[-1, 2] + SIDE_DOWN) < 1e-3  # the overmould (12 mm above the tip) on the block's top edge
    force = env.unwrapped.ft.buffer[0, -1, :3].cpu().numpy()
    assert force[0] > 20 and force[2] < -20  # into the side and down, as a policy stuck beside the block presses


@pytest.mark.parametrize("task", TASKS)
def test_a_turned_hold_holds_the_part_turned_and_tilted_where_an_upright_one_holds_it_upright(task):
    """``HoldPolicy(turn=)``: the tip where asked, turned about its axis and tilted as asked (as the success test
    measures them); a round part is only tilted, since it has no turn about its axis to hold, and a part that fits
    every quarter or sixth of a turn is turned 3/4 of the way to its next fit."""
    import numpy as np
    import torch
    from mani_skill.utils.geometry.rotation_conversions import axis_angle_to_quaternion
    from mani_skill.utils.structs import Pose

    from drem_maniskill.experts.scripted import HoldPolicy
    from drem_maniskill.evaluate.probes import TURN, TURN_STEPS, TURNED_HOVER, hold_targets, hold_turns

    env = make_env(task, obs_mode="state_dict")
    u = env.unwrapped
    target, turn = hold_targets(env)[TURNED_HOVER], hold_turns(env)[TURNED_HOVER]
    assert (turn == TURN) == (u.yaw_symmetry < 2) and abs(turn[2]) <= abs(TURN[2])
    vec = torch.tensor([[turn[0], turn[1], turn[2] if u.yaw_symmetry else 0.0]])
    asked = u.orientation_errors(Pose.create_from_pq(torch.zeros(1, 3), axis_angle_to_quaternion(vec)))
    tilt_asked, yaw_asked = (float(np.degrees(a[0])) for a in asked)
    if u.yaw_symmetry == 1:
        assert abs(tilt_asked - 10.7) < 0.1 and abs(yaw_asked - 55.2) < 0.1  # TURN itself
    for held, tilt_deg, yaw_deg in ((None, 0.0, 0.0), (turn, tilt_asked, yaw_asked)):
        obs, _ = env.reset(seed=3)
        pi = HoldPolicy(env, target, turn=held)
        for _ in range(TURN_STEPS):  # as the examination holds it
            obs, *_ = env.step(pi(obs))
        rel = u.tip_pose_in_socket()
        tilt, yaw = (float(np.degrees(a[0].cpu())) for a in u.orientation_errors(rel))
        assert abs(rel.p[0].cpu().numpy() - np.asarray(target)).max() < 5e-4
        assert abs(tilt - tilt_deg) < 1.5 and abs(yaw - yaw_deg) < 2.0, (tilt, yaw)
