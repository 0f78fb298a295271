"""The one rule for camera roles, and camera images from an observation or rendered once."""

from __future__ import annotations

import gymnasium as gym
import torch

from drem_maniskill.utils.cameras import camera_images, camera_roles, env_cameras


def test_camera_roles_for_our_tasks_stock_tasks_and_odd_sets():
    assert camera_roles(["fixed_camera", "wrist_camera"]) == {"fixed": "fixed_camera", "wrist": "wrist_camera"}
    # h5py lists recorded cameras alphabetically: the roles must not depend on the order.
    assert camera_roles(["wrist_camera", "fixed_camera"]) == {"fixed": "fixed_camera", "wrist": "wrist_camera"}
    assert camera_roles(["aux_camera", "wrist_camera", "fixed_camera"])["fixed"] == "fixed_camera"
    assert camera_roles(["base_camera", "hand_camera"]) == {"fixed": "base_camera", "wrist": "hand_camera"}
    assert camera_roles(["base_camera"]) == {"fixed": "base_camera"}
    assert camera_roles(["hand_camera"]) == {"fixed": "hand_camera"}
    assert camera_roles([]) == {}


def test_camera_images_come_from_the_obs_or_are_rendered_the_same():
    env = gym.make("PegInHole-v1", obs_mode="rgb")
    try:
        obs, _ = env.reset(seed=3)
        uids = env_cameras(env)
        assert uids == ["fixed_camera", "wrist_camera"]
        from_obs = camera_images(env, obs, uids)
        for uid in uids:
            assert from_obs[uid].data_ptr() == obs["sensor_data"][uid]["rgb"].data_ptr()  # the obs' own tensor
        rendered = camera_images(env, {"agent": {}}, uids)  # an obs without images: render once
        for uid in uids:
            assert rendered[uid].shape == (1, 128, 128, 3) and rendered[uid].dtype == torch.uint8
            assert torch.equal(rendered[uid], from_obs[uid])
    finally:
        env.close()
