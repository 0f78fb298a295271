"""Every ManiSkill obs mode on our tasks."""

from __future__ import annotations

import pytest
import torch

import drem_maniskill  # noqa: F401  (registers the tasks; conftest imports it too)
from tests.envs.tooling import (
    CAMERAS,
    FT,
    FT_HISTORY,
    IMG,
    MOVE,
    STATE_DIM,
    ft_buffer,
    leaves,
    make_quiet,
)

pytestmark = [
    pytest.mark.filterwarnings("ignore::UserWarning"),
    pytest.mark.filterwarnings("ignore::DeprecationWarning"),
]


SENSOR_KEYS = {
    "rgb": {"rgb": ((1, IMG, IMG, 3), torch.uint8)},
    "rgbd": {"rgb": ((1, IMG, IMG, 3), torch.uint8), "depth": ((1, IMG, IMG, 1), torch.int16)},
    "depth": {"depth": ((1, IMG, IMG, 1), torch.int16)},
    "sensor_data": {"Color": ((1, IMG, IMG, 4), torch.uint8),
                    "PositionSegmentation": ((1, IMG, IMG, 4), torch.int16)},
}


STATE_EXTRA = {"tcp_pose", "ft", "part_pose", "socket_pose", "tip_in_socket"}


VISUAL_EXTRA = {"tcp_pose", "ft"}


@pytest.mark.parametrize(
    "obs_mode", ["state", "state_dict", "none", "rgb", "rgbd", "depth", "sensor_data", "pointcloud"]
)
def test_obs_modes(obs_mode):
    env = make_quiet(obs_mode)
    try:
        env.reset(seed=0)
        obs, reward, *_ = env.step(MOVE)
        assert reward.shape == (1,)
        ft = ft_buffer(env)
        assert ft.abs().sum() > 0  # so that the equalities below say something

        if obs_mode == "state":
            assert isinstance(obs, torch.Tensor) and obs.shape == (1, STATE_DIM)
            assert env.observation_space.shape == (1, STATE_DIM)
            torch.testing.assert_close(obs[:, FT], ft.reshape(1, -1))
            return
        if obs_mode == "none":
            assert obs == {} and len(env.observation_space.spaces) == 0
            return

        assert isinstance(obs, dict)
        # Every leaf matches the declared observation space.
        space_leaves = leaves(env.observation_space)
        obs_leaves = leaves(obs)
        assert set(space_leaves) == set(obs_leaves)
        for key, value in obs_leaves.items():
            assert tuple(space_leaves[key].shape) == tuple(value.shape), key

        assert set(obs["agent"]) == {"qpos", "qvel"}
        assert obs["agent"]["qpos"].shape == (1, 9)
        torch.testing.assert_close(obs["extra"]["ft"], ft)
        assert obs["extra"]["ft"].shape == (1, FT_HISTORY, 6)
        assert obs["extra"]["tcp_pose"].shape == (1, 7)

        if obs_mode == "state_dict":
            assert set(obs) == {"agent", "extra"}
            assert set(obs["extra"]) == STATE_EXTRA
            assert obs["extra"]["tip_in_socket"].shape == (1, 3)
            return

        # Visual modes: no privileged state in "extra", both cameras' parameters.
        assert set(obs["extra"]) == VISUAL_EXTRA
        assert set(obs["sensor_param"]) == set(CAMERAS)
        for cam in CAMERAS:
            assert obs["sensor_param"][cam]["intrinsic_cv"].shape == (1, 3, 3)
        if obs_mode == "pointcloud":
            # ManiSkill leaves an empty "sensor_data" next to the fused point cloud.
            assert set(obs) == {"agent", "extra", "sensor_param", "sensor_data", "pointcloud"}
            assert obs["sensor_data"] == {}
            n = len(CAMERAS) * IMG * IMG
            pc = obs["pointcloud"]
            assert pc["xyzw"].shape == (1, n, 4) and pc["rgb"].shape == (1, n, 3)
            assert pc["segmentation"].shape == (1, n, 1)
            assert (pc["xyzw"][..., 3] > 0).any()  # some valid points
            return

        assert set(obs) == {"agent", "extra", "sensor_param", "sensor_data"}
        assert set(obs["sensor_data"]) == set(CAMERAS)
        for cam in CAMERAS:
            data = obs["sensor_data"][cam]
            assert set(data) == set(SENSOR_KEYS[obs_mode])
            for key, (shape, dtype) in SENSOR_KEYS[obs_mode].items():
                assert data[key].shape == shape and data[key].dtype == dtype, (cam, key)
            if "depth" in data:
                assert (data["depth"] > 0).float().mean() > 0.5  # the scene fills the view
    finally:
        env.close()
