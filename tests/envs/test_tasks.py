"""Behaviour of our tasks (envs.TASKS): spaces, rewards, determinism, state, F/T, success, physics."""

from __future__ import annotations

import math

import gymnasium as gym
import numpy as np
import pytest
import torch

from drem_maniskill.envs.agent import EE_POS_LIMIT
from tests.conftest import TASKS, hand_to_part, make_env, run_policy


@pytest.mark.parametrize("task", TASKS)
def test_observation_and_action_spaces(task):
    env = make_env(task, obs_mode="rgb")
    obs, info = env.reset(seed=0)
    assert env.action_space.shape == (6,)
    assert obs["extra"]["ft"].shape == (1, 8, 6) and obs["extra"]["ft"].dtype == torch.float32
    assert obs["extra"]["tcp_pose"].shape == (1, 7)
    for cam in ("fixed_camera", "wrist_camera"):
        rgb = obs["sensor_data"][cam]["rgb"]
        assert rgb.shape == (1, 128, 128, 3) and rgb.dtype == torch.uint8
        # A real picture, not a blank frame: flat-shaded, but several distinct colours.
        assert len(torch.unique(rgb.reshape(-1, 3), dim=0)) >= 6
    u = env.unwrapped
    assert u.sim_freq >= 100 and u.control_freq == 5
    assert u.control_mode == "pd_ee_delta_pose"


@pytest.mark.parametrize("task", TASKS)
def test_reward_modes(task):
    values = {}
    for mode in ("sparse", "dense", "normalized_dense", "none"):
        env = make_env(task, obs_mode="state_dict", reward_mode=mode)
        env.reset(seed=1)
        _, reward, *_ = env.step(torch.zeros(1, 6))
        assert reward.shape == (1,)
        values[mode] = reward.item()
    assert values["sparse"] == 0.0 and values["none"] == 0.0
    assert 0 < values["dense"] < 6
    assert values["normalized_dense"] == pytest.approx(values["dense"] / 6, rel=1e-5)

    env = make_env(task, obs_mode="state_dict", reward_mode="normalized_dense")
    _, info, _ = run_policy(env, "expert", seed=1)
    assert info["success"].item()
    reward = env.unwrapped.get_reward(obs=None, action=None, info=info)
    assert reward.item() == pytest.approx(1.0)


@pytest.mark.parametrize("task", TASKS)
def test_dense_reward_rises_along_the_expert(task):
    env = make_env(task, obs_mode="state_dict", reward_mode="normalized_dense")
    from drem_maniskill.experts import get_policy, rollout

    rewards = rollout(env, get_policy("expert", env), seed=2).rewards
    assert rewards[-1] == 1.0
    assert rewards[-1] > rewards[len(rewards) // 2] > rewards[0]


@pytest.mark.parametrize("clearance", [0.0, -0.001, float("nan"), 0.5, "wide"])
def test_bad_clearance_is_a_clear_error(clearance):
    with pytest.raises(ValueError, match=r"clearance must be a positive diametral gap in metres.*0\.0024"):
        gym.make("PegInHole-v1", clearance=clearance)


def test_clearance_changes_the_bore():
    tight = gym.make("PegInHole-v1", clearance=0.001, obs_mode="state_dict")
    try:
        assert tight.unwrapped.clearance == 0.001
        # The ring's inner faces sit at the peg radius plus half the clearance.
        shapes = tight.unwrapped.socket._bodies[0].get_collision_shapes()
        ring = [s for s in shapes if abs(s.local_pose.p[2] - (0.010 + 0.020)) < 1e-6]
        inner = min(np.linalg.norm(s.local_pose.p[:2]) - s.half_size[0] for s in ring)
        assert inner == pytest.approx(0.010 + 0.0005, abs=1e-6)
        assert len(ring) >= 24
    finally:
        tight.close()


@pytest.mark.parametrize("task", TASKS)
def test_seeded_resets_are_reproducible(task):
    env = make_env(task, obs_mode="rgb")
    first, _ = env.reset(seed=7)
    socket_a = env.unwrapped.socket.pose.raw_pose.clone()
    second, _ = env.reset(seed=7)
    torch.testing.assert_close(first["extra"]["tcp_pose"], second["extra"]["tcp_pose"])
    assert torch.equal(first["sensor_data"]["fixed_camera"]["rgb"], second["sensor_data"]["fixed_camera"]["rgb"])
    other, _ = env.reset(seed=8)
    assert not torch.allclose(socket_a, env.unwrapped.socket.pose.raw_pose)
    assert not torch.allclose(first["extra"]["tcp_pose"], other["extra"]["tcp_pose"])
    # Colours are randomised per seed too.
    a = first["sensor_data"]["fixed_camera"]["rgb"].float().mean((1, 2))
    b = other["sensor_data"]["fixed_camera"]["rgb"].float().mean((1, 2))
    assert not torch.allclose(a, b)


def test_colours_fixed_when_not_randomized():
    env = gym.make("PegInHole-v1", obs_mode="state_dict", randomize_colors=False)
    try:
        env.reset(seed=1)
        c1 = list(env.unwrapped._part_materials[0].base_color)
        env.reset(seed=2)
        assert list(env.unwrapped._part_materials[0].base_color) == c1
    finally:
        env.close()


def _press_until_contact(env, steps: int = 12):
    """Drive the tip down next to the opening so that it presses on the socket's top face."""
    from drem_maniskill.experts import get_policy

    policy = get_policy("expert", env)
    u = env.unwrapped
    obs, _ = env.reset(seed=3)
    free = []
    for _ in range(steps):
        tip = u.tip_pose_in_socket().p
        target = torch.tensor([[0.0, 0.015 if u.yaw_symmetry == 0 else 0.0, -0.004]])
        if u.yaw_symmetry:
            target[0, 0] = 0.0085  # on the housing wall beside the USB opening
        obs, *_ = env.step(policy.move(target, speed=0.5))
        if tip[0, 2] > 0.02:
            free.append(obs["extra"]["ft"][0, :, 2].abs().mean().item())
    return obs, free


@pytest.mark.parametrize("task", TASKS)
def test_ft_reads_contact_along_the_insertion_axis(task):
    env = make_env(task, obs_mode="state_dict")
    obs, free = _press_until_contact(env)
    pressed = obs["extra"]["ft"][0, :, 2].abs().mean().item()
    assert max(free) < 1.0  # free space reads about zero (gravity off on the held part)
    assert pressed > max(free) + 3.0, (pressed, free)
    # Pressing on the face does not count as inserted.
    assert not env.unwrapped.evaluate()["success"].item()


def _replay(env, state, action):
    env.unwrapped.set_state_dict(state)
    obs, *_ = env.step(action)
    return obs


@pytest.mark.parametrize("task", TASKS)
def test_state_round_trip_in_free_space_is_exact(task):
    env = make_env(task, obs_mode="rgb")
    u = env.unwrapped
    env.reset(seed=4)
    env.step(torch.tensor([[0.2, 0.1, -0.3, 0.0, 0.1, 0.0]]))
    state = u.get_state_dict()
    action = torch.tensor([[0.3, -0.2, -0.5, 0.1, 0.0, -0.2]])
    first, *_ = env.step(action)
    for _ in range(3):  # wander off, then come back
        env.step(torch.rand(1, 6) * 2 - 1)
    second = _replay(env, state, action)
    torch.testing.assert_close(first["extra"]["ft"], second["extra"]["ft"], atol=0.05, rtol=0)
    torch.testing.assert_close(first["extra"]["tcp_pose"], second["extra"]["tcp_pose"], atol=1e-5, rtol=0)
    for cam in ("fixed_camera", "wrist_camera"):
        diff = (first["sensor_data"][cam]["rgb"].int() - second["sensor_data"][cam]["rgb"].int()).abs()
        assert diff.float().mean() < 0.05


@pytest.mark.parametrize("task", TASKS)
def test_state_round_trip_in_contact_restores_the_ft_history(task):
    env = make_env(task, obs_mode="state_dict")
    u = env.unwrapped
    _press_until_contact(env, steps=8)  # pressing: the F/T history is far from zero
    state = u.get_state_dict()
    assert state["task"]["ft_history"].abs().max() > 3.0
    gen = torch.Generator().manual_seed(0)
    for _ in range(4):
        env.step(torch.rand(1, 6, generator=gen) * 2 - 1)
    u.set_state_dict(state)
    torch.testing.assert_close(u.ft.buffer, state["task"]["ft_history"].reshape(1, 8, 6))
    restored = u.get_state_dict()
    for group in ("actors", "articulations"):
        for name, value in state[group].items():
            torch.testing.assert_close(restored[group][name], value, atol=1e-6, rtol=0)
    torch.testing.assert_close(restored["task"]["drive_targets"], state["task"]["drive_targets"])

    # The flat state vector carries the task keys too.
    flat = u.get_state()
    assert flat.shape[1] > 48
    env.step(torch.rand(1, 6, generator=gen) * 2 - 1)
    u.set_state(flat)
    torch.testing.assert_close(u.get_state(), flat, atol=1e-5, rtol=0)


@pytest.mark.parametrize("task", TASKS)
def test_a_state_in_contact_replays_its_step_without_persistent_contact_manifolds(task):
    # With PhysX's persistent contact manifolds (PCM, ManiSkill's default) a step from a restored
    # contact state depends on the contacts that the step run before it left behind, which no
    # state holds: on USBInsertion-v1 replays then differ by up to 4.5 mm and 89 N. Without
    # PCM a restored state replays its step whatever ran before.
    env = gym.make(task, obs_mode="state_dict", sim_config=dict(scene_config=dict(enable_pcm=False)))
    try:
        u = env.unwrapped
        _press_until_contact(env, steps=8)
        state = u.get_state_dict()
        action = torch.tensor([[0.3, -0.2, -0.5, 0.1, 0.0, -0.2]])
        first, *_ = env.step(action)
        scale = first["extra"]["ft"].abs().max()
        assert scale > 3.0  # in contact
        gen = torch.Generator().manual_seed(0)
        for wander in range(3):
            for _ in range(wander):
                env.step(torch.rand(1, 6, generator=gen) * 2 - 1)
            replay = _replay(env, state, action)
            assert (first["extra"]["ft"] - replay["extra"]["ft"]).abs().max() < 0.1 * scale
            torch.testing.assert_close(first["extra"]["tcp_pose"], replay["extra"]["tcp_pose"], atol=2e-4, rtol=0)
    finally:
        env.close()


def test_flat_state_of_another_task_is_rejected():
    peg = make_env("PegInHole-v1", obs_mode="state_dict")
    usb = make_env("USBInsertion-v1", obs_mode="state_dict")
    peg.reset(seed=0)
    usb.reset(seed=0)
    bad = torch.cat([usb.unwrapped.get_state(), torch.zeros(1, 5)], dim=1)
    with pytest.raises(ValueError, match="flat state has"):
        usb.unwrapped.set_state(bad)


@pytest.mark.parametrize("task", TASKS)
def test_start_region_and_success(task):
    env = make_env(task, obs_mode="state_dict")
    u = env.unwrapped
    for seed in range(5):
        env.reset(seed=seed)
        region = u.in_start_region()
        assert region.dtype == torch.bool and region.shape == (1,)
        assert region.item()
        assert not u.evaluate()["success"].item()
    _, info, _ = run_policy(env, "expert", seed=11)
    assert info["success"].item()
    assert not u.in_start_region().item()
    assert info["insertion_depth"].item() >= 0.8 * u.hole_depth
    # The part never slipped in the hand on its way in.
    rel = hand_to_part(env)[0]
    assert torch.allclose(rel[:3], torch.tensor(u.part_in_hand.p), atol=1e-3)


def test_part_is_held_firmly_while_scraping_over_the_socket():
    env = make_env("PegInHole-v1", obs_mode="state_dict")
    u = env.unwrapped
    start = None
    for seed in range(3):
        _, info, _ = run_policy(env, "search_fail", seed=seed, stop_on_success=False)
        rel = hand_to_part(env)[0]
        start = torch.tensor([*u.part_in_hand.p, *u.part_in_hand.q])
        assert torch.allclose(rel[:3], start[:3], atol=1e-3)
        angle = 2 * math.acos(min(1.0, abs(float(torch.dot(rel[3:], start[3:])))))
        assert angle < math.radians(1.0)
        assert not info["success"].item()


@pytest.mark.parametrize("task", TASKS)
def test_fingers_rest_on_the_part_from_the_first_observation(task):
    """The fingers stand on the part's surface (not inside it) at reset and stay there, in contact too.

    The finger joint is the distance of each finger's pad from the hand's axis; the part is
    ``grip_half_width`` from the axis where the fingers hold it.
    """
    env = make_env(task, obs_mode="state_dict")
    u = env.unwrapped
    obs, _ = env.reset(seed=4)
    width = u.grip_half_width
    fingers = lambda q: q[0, u._finger_idx]  # noqa: E731
    assert torch.allclose(fingers(obs["agent"]["qpos"]), torch.full((2,), width), atol=1e-4)
    assert u.agent.controller.controllers["gripper"].config.target == width
    _, info, _ = run_policy(env, "search_fail", seed=4, stop_on_success=False)  # scrapes over the socket
    assert torch.allclose(fingers(u.agent.robot.get_qpos()), torch.full((2,), width), atol=5e-4)


@pytest.mark.parametrize("task", ["USBInsertion-v1", "DPegInHole-v1"])
def test_a_keyed_part_enters_only_one_way_round(task):
    """The expert, told the part is symmetric under a half turn, aligns it flipped: blocked."""
    env = make_env(task, obs_mode="state_dict")
    u = env.unwrapped
    results = {}
    for flipped in (False, True):
        obs, _ = env.reset(seed=21)
        if flipped:
            # Turn the receptacle by half a turn; the policy aims for either orientation.
            pose = u.socket.pose
            from mani_skill.utils.geometry.rotation_conversions import (
                quaternion_multiply,
            )
            from mani_skill.utils.structs import Pose

            from drem_maniskill.envs.placement import yaw_quat

            turned = quaternion_multiply(yaw_quat(torch.tensor([math.pi])), pose.q)
            u.socket.set_pose(Pose.create_from_pq(pose.p, turned))
            u.yaw_symmetry = 2
        from drem_maniskill.experts import get_policy

        policy = get_policy("expert", env)
        u.yaw_symmetry = 2 if flipped else 1
        for _ in range(40):
            obs, _, _, _, info = env.step(policy(obs))
        u.yaw_symmetry = 1
        results[flipped] = info["insertion_depth"].item()
    assert results[False] >= 0.8 * u.hole_depth
    assert results[True] < 0.3 * u.hole_depth, results


@pytest.mark.parametrize("task", TASKS)
def test_the_opening_admits_the_part_within_its_gap_and_not_half_a_millimetre_past_it(task):
    """Held upright above the opening at an offset across the axis (socket frame x, then y), then lowered 2 mm a step,
    the part enters at half its radial gap (``clearance`` / 2) and rests on the face half a millimetre past it."""
    from drem_maniskill.experts.scripted import HoldPolicy

    env = make_env(task, obs_mode="state_dict")
    u = env.unwrapped
    gap = u.clearance / 2
    for axis in (0, 1):
        depths = {}
        for offset in (gap / 2, gap + 0.0005):
            above = [0.0, 0.0, 0.003]
            above[axis] = offset
            obs, _ = env.reset(seed=2)
            for target, speed in ((above, 0.5), ([*above[:2], -0.012], 0.1)):
                policy = HoldPolicy(env, target, speed=speed)
                for _ in range(10):
                    obs, *_ = env.step(policy(obs))
            depths[offset] = -u.tip_pose_in_socket().p[0, 2].item()
        inside, outside = depths.values()
        assert inside > 0.011 and outside < 0.001, (axis, depths)


def test_action_scale_is_fine_enough():
    env = make_env("PegInHole-v1", obs_mode="state_dict")
    env.reset(seed=0)
    before = env.unwrapped.agent.tcp.pose.p.clone()
    action = torch.zeros(1, 6)
    action[0, 0] = 1.0
    env.step(action)
    moved = (env.unwrapped.agent.tcp.pose.p - before)[0, 0].item()
    assert 0.5 * EE_POS_LIMIT < moved < 1.2 * EE_POS_LIMIT
