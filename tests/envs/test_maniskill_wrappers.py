"""ManiSkill's wrappers on our tasks: CPUGymWrapper, ManiSkillVectorEnv, FlattenRGBDObservationWrapper."""

from __future__ import annotations

import numpy as np
import pytest
import torch

import drem_maniskill  # noqa: F401  (registers the tasks; conftest imports it too)
from drem_maniskill.experts import get_policy
from tests.envs.tooling import (
    CAMERAS,
    FT,
    FT_HISTORY,
    IMG,
    MOVE,
    PART_POSE,
    QPOS,
    STATE_DIM,
    TCP,
    ft_buffer,
    make_quiet,
)

pytestmark = [
    pytest.mark.filterwarnings("ignore::UserWarning"),
    pytest.mark.filterwarnings("ignore::DeprecationWarning"),
]


@pytest.fixture(scope="module")
def state_env():
    env = make_quiet("state")
    yield env
    env.close()


def test_cpu_gym_wrapper_state(state_env):
    from mani_skill.utils.wrappers.gymnasium import CPUGymWrapper

    env = CPUGymWrapper(state_env, record_metrics=True)
    assert env.observation_space.shape == (STATE_DIM,)
    assert env.action_space.shape == (6,)

    obs, info = env.reset(seed=0)
    assert isinstance(obs, np.ndarray) and obs.ndim == 1 and obs.dtype == np.float32
    assert obs.shape == env.observation_space.shape
    assert env.observation_space.contains(obs)
    assert isinstance(info["success"], (bool, np.bool_))
    np.testing.assert_array_equal(obs[FT], 0.0)  # reset clears the F/T history

    action = env.action_space.sample()
    assert isinstance(action, np.ndarray)
    obs, reward, terminated, truncated, info = env.step(action)
    assert isinstance(obs, np.ndarray) and obs.shape == (STATE_DIM,)
    assert isinstance(reward, float)
    assert isinstance(terminated, (bool, np.bool_)) and isinstance(truncated, (bool, np.bool_))
    assert not terminated and not truncated
    assert int(info["elapsed_steps"]) == 1
    assert info["episode"]["episode_len"] == 1 and info["episode"]["success_once"] == False  # noqa: E712

    # The flat vector is the unbatched obs dict: check where the task's pieces land.
    u = state_env.unwrapped
    np.testing.assert_allclose(obs[QPOS], u.agent.robot.get_qpos()[0].numpy(), atol=1e-6)
    np.testing.assert_allclose(obs[TCP], u.agent.tcp.pose.raw_pose[0].numpy(), atol=1e-6)
    np.testing.assert_allclose(obs[FT], ft_buffer(u)[0].reshape(-1).numpy(), atol=1e-6)
    np.testing.assert_allclose(obs[PART_POSE], u.part.pose.raw_pose[0].numpy(), atol=1e-6)
    assert np.abs(obs[FT]).sum() > 0  # a physics step filled the history


@pytest.fixture(scope="module")
def short_env():
    env = make_quiet("state", num_envs=1, max_episode_steps=3)
    yield env
    env.close()


@pytest.fixture(scope="module")
def long_env():
    env = make_quiet("state", num_envs=1)
    yield env
    env.close()


def _vec(env, **kwargs):
    from mani_skill.vector.wrappers.gymnasium import ManiSkillVectorEnv

    return ManiSkillVectorEnv(env, **kwargs)


def test_vector_env_spaces_and_truncation_auto_reset(short_env):
    vec = _vec(short_env, auto_reset=True, ignore_terminations=False, record_metrics=True)
    assert vec.num_envs == 1
    assert vec.single_observation_space.shape == (STATE_DIM,)
    assert vec.observation_space.shape == (1, STATE_DIM)
    # ManiSkill keeps the action space unbatched when num_envs == 1 (for every task).
    assert vec.single_action_space.shape == (6,) and vec.action_space.shape == (6,)

    obs, info = vec.reset(seed=0)
    assert obs.shape == (1, STATE_DIM)
    for t in range(1, 4):
        obs, rew, term, trunc, info = vec.step(MOVE)
        assert obs.shape == (1, STATE_DIM) and rew.shape == (1,)
        assert term.shape == (1,) and trunc.shape == (1,) and term.dtype == torch.bool
        if t < 3:
            assert not trunc.any() and "final_observation" not in info
    # Step 3 hit max_episode_steps=3: truncated, and the wrapper reset the env in the same step.
    assert trunc.all() and not term.any()
    assert info["_final_info"].all() and info["_final_observation"].all()
    final_obs, final_info = info["final_observation"], info["final_info"]
    assert int(final_info["elapsed_steps"].item()) == 3
    assert int(final_info["episode"]["episode_len"].item()) == 3
    assert int(vec.base_env.elapsed_steps.item()) == 0
    # The returned obs is the new episode's: its F/T history was cleared, the final one was not.
    assert torch.all(obs[:, FT] == 0)
    assert final_obs[:, FT].abs().sum() > 0
    vec.step(MOVE)
    assert int(vec.base_env.elapsed_steps.item()) == 1


def test_vector_env_without_auto_reset_keeps_running(short_env):
    vec = _vec(short_env, auto_reset=False)
    vec.reset(seed=0)
    zero = torch.zeros(1, 6)
    for _ in range(4):
        obs, rew, term, trunc, info = vec.step(zero)
        assert "final_observation" not in info
    assert trunc.all()
    assert int(vec.base_env.elapsed_steps.item()) == 4


def _run_expert_until(vec, stop, max_steps=50):
    policy = get_policy("expert", vec)
    obs, info = vec.reset(seed=0)
    for t in range(1, max_steps + 1):
        obs, rew, term, trunc, info = vec.step(policy(obs))
        if stop(term, trunc, info):
            return t, obs, term, trunc, info
    raise AssertionError(f"stop condition not met in {max_steps} steps")


def test_vector_env_terminates_and_auto_resets_on_success(long_env):
    vec = _vec(long_env, auto_reset=True, ignore_terminations=False)
    t, obs, term, trunc, info = _run_expert_until(vec, lambda te, tr, i: bool(te.any() or tr.any()))
    assert t < 50 and term.all() and not trunc.any()
    assert info["final_info"]["success"].all()
    assert int(info["final_info"]["elapsed_steps"].item()) == t
    assert int(vec.base_env.elapsed_steps.item()) == 0
    assert not info["success"].any()  # info of the fresh episode


def test_vector_env_ignore_terminations(long_env):
    vec = _vec(long_env, auto_reset=True, ignore_terminations=True, record_metrics=True)
    t, obs, term, trunc, info = _run_expert_until(vec, lambda te, tr, i: bool(i["success"].any()))
    assert not term.any() and "final_observation" not in info
    assert info["episode"]["success_once"].all() and info["episode"]["success_at_end"].all()
    obs, rew, term, trunc, info = vec.step(torch.zeros(1, 6))
    assert not term.any() and "final_observation" not in info
    assert int(vec.base_env.elapsed_steps.item()) == t + 1
    assert info["episode"]["success_once"].all()


@pytest.fixture(scope="module")
def flat_rgb_env():
    from mani_skill.utils.wrappers.flatten import FlattenRGBDObservationWrapper

    base = make_quiet("rgb")
    env = FlattenRGBDObservationWrapper(base, rgb=True, depth=True, state=True)
    yield env
    env.close()


def test_flatten_rgbd_wrapper_rgb(flat_rgb_env):
    env = flat_rgb_env
    obs, _ = env.reset(seed=0)
    assert set(obs) == {"rgb", "state"}  # depth requested but the rgb obs mode has none
    obs, *_ = env.step(MOVE)
    assert set(obs) == {"rgb", "state"}
    assert obs["rgb"].shape == (1, IMG, IMG, 6) and obs["rgb"].dtype == torch.uint8
    # rgb obs: extra has tcp_pose and ft only -> qpos 9 + qvel 9 + tcp 7 + ft 48
    assert obs["state"].shape == (1, 9 + 9 + 7 + 6 * FT_HISTORY)
    ft = ft_buffer(env)
    assert ft.abs().sum() > 0
    torch.testing.assert_close(obs["state"][:, -6 * FT_HISTORY:], ft.reshape(1, -1))
    u = env.unwrapped
    torch.testing.assert_close(obs["state"][:, QPOS], u.agent.robot.get_qpos())
    torch.testing.assert_close(obs["state"][:, TCP], u.agent.tcp.pose.raw_pose)
    # Channels are the cameras in sensor order: fixed_camera then wrist_camera.
    raw = u.get_obs()
    for i, cam in enumerate(CAMERAS):
        torch.testing.assert_close(obs["rgb"][..., 3 * i: 3 * i + 3], raw["sensor_data"][cam]["rgb"])
    # The wrapper updated the observation space to the flattened layout.
    space = u.observation_space
    assert space["rgb"].shape == (1, IMG, IMG, 6) and space["state"].shape == obs["state"].shape


def test_flatten_rgbd_wrapper_rgbd_separate_depth():
    from mani_skill.utils.wrappers.flatten import FlattenRGBDObservationWrapper

    base = make_quiet("rgbd")
    try:
        env = FlattenRGBDObservationWrapper(base, rgb=True, depth=True, state=True, sep_depth=True)
        obs, _ = env.reset(seed=0)
        assert set(obs) == {"rgb", "depth", "state"}
        assert obs["rgb"].shape == (1, IMG, IMG, 6)
        assert obs["depth"].shape == (1, IMG, IMG, 2)
        assert obs["state"].shape == (1, 25 + 6 * FT_HISTORY)
        assert (obs["depth"] > 0).any()
    finally:
        base.close()
