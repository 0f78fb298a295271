"""ManiSkill envs, ours and ManiSkill's own, skip SAPIEN's BRDF table and render the same images as with it."""

from __future__ import annotations

import warnings
from types import SimpleNamespace

import gymnasium as gym
import numpy as np
import pytest
import torch

import drem_maniskill  # noqa: F401  (registers the tasks)
from drem_maniskill.envs import rendering


def _pictures(monkeypatch, task: str, kwargs: dict, skip: bool) -> tuple:
    """Every camera's images (both sensors and the render camera) over a few random steps, and how many cameras
    got the blank table."""
    given, real = [], rendering.skip_brdf_lut

    def record(scene, cameras):
        given.append(real(scene, cameras) if skip else 0)
        return given[-1]

    monkeypatch.setattr(rendering, "skip_brdf_lut", record)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        env = gym.make(task, obs_mode="rgb", render_mode="rgb_array", **kwargs)
    try:
        obs, _ = env.reset(seed=3)
        actions = torch.rand((3, *env.action_space.shape), generator=torch.Generator().manual_seed(0)) * 2 - 1
        frames = []
        for action in actions:
            obs, *_ = env.step(action.numpy())
            frames += [v["rgb"].cpu().numpy() for v in obs["sensor_data"].values()]
            frames.append(np.asarray(env.render().cpu()))
        return frames, given
    finally:
        env.close()


@pytest.mark.filterwarnings("ignore::UserWarning")
@pytest.mark.parametrize("task, kwargs", [("USBInsertion-v1", {"render_style": "full"}), ("PlugCharger-v1", {})])
def test_a_blank_brdf_table_renders_every_camera_bit_for_bit_as_sapiens_own(monkeypatch, task, kwargs):
    blank, given = _pictures(monkeypatch, task, kwargs, skip=True)
    # Two sensors and the render camera, given again at every reconfiguration.
    assert given and all(n == 3 for n in given)
    computed, _ = _pictures(monkeypatch, task, kwargs, skip=False)
    assert len(blank) == len(computed) == 9
    for a, b in zip(blank, computed):
        assert a.shape == b.shape and a.std() > 0
        np.testing.assert_array_equal(a, b)


def test_a_scene_with_an_environment_map_keeps_sapiens_table():
    lit = SimpleNamespace(sub_scenes=[SimpleNamespace(render_system=SimpleNamespace(cubemap=object()))])
    assert rendering.has_environment_map(lit)
    # Cameras are not even read: the scene's environment map rules the blank table out.
    assert rendering.skip_brdf_lut(lit, cameras=None) == 0


def test_importing_the_package_hooks_the_blank_table_into_maniskill_once():
    from mani_skill.envs.sapien_env import BaseEnv

    assert getattr(BaseEnv._setup_sensors, "blank_brdf_lut", False)  # installed by `import drem_maniskill`
    hooked = BaseEnv._setup_sensors
    assert rendering.install() is False and BaseEnv._setup_sensors is hooked
