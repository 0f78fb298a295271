"""A blank BRDF lookup table for cameras in scenes without an environment map.

SAPIEN's rasterizing shaders bind a BRDF lookup table (``samplerBRDFLUT``) for image-based specular light, and
SAPIEN computes it with a compute shader the first time a process renders: on a CPU Vulkan driver (lavapipe)
about 12 s of CPU in every process that renders, longer than most of what follows. The table only scales the
environment map's colour (``color * (fresnel * lut.x + lut.y)``), and a scene without an environment map samples
SAPIEN's black default cubemap, so there the term is zero whatever the table holds: a blank table gives the same
images bit for bit (``tests/envs/test_rendering.py``) without the computation.

``install()`` (run when ``drem_maniskill.envs`` is imported) hooks this into ManiSkill's ``BaseEnv._setup_sensors``,
so every ManiSkill env made in the process, ManiSkill's own tasks (PushCube-v1, PlugCharger-v1, ...) as well as ours,
takes the blank table when its scene has no environment map; a scene with one keeps SAPIEN's table.
"""

from __future__ import annotations

import functools

import numpy as np
import sapien


def has_environment_map(scene) -> bool:
    """True when any sub-scene of a ManiSkill scene has an environment map (a cubemap) set."""
    return any(s.render_system.cubemap is not None for s in scene.sub_scenes)


def render_cameras(cameras: dict) -> list:
    """The SAPIEN render cameras of ManiSkill ``Camera`` sensors (one per sub-scene each)."""
    return [c for sensor in cameras.values() for c in getattr(sensor.camera, "_render_cameras", [])]


def skip_brdf_lut(scene, cameras: dict) -> int:
    """Give ``cameras`` a blank BRDF lookup table when ``scene`` has no environment map; returns how many got it."""
    if has_environment_map(scene):
        return 0
    blank = sapien.render.RenderTexture(np.zeros((1, 1, 4), np.float32), 2, "R32G32B32A32Sfloat",
                                        address_mode="edge")
    targets = render_cameras(cameras)
    for camera in targets:
        camera.set_texture("BRDFLUT", blank)
    return len(targets)


def install() -> bool:
    """Hook ``skip_brdf_lut`` into every ManiSkill env's sensor set-up (once a process); True when this call did."""
    from mani_skill.envs.sapien_env import BaseEnv

    original = BaseEnv._setup_sensors
    if getattr(original, "blank_brdf_lut", False):
        return False

    @functools.wraps(original)
    def _setup_sensors(self, options: dict):
        original(self, options)
        # After ManiSkill made the cameras and before the reset takes their first pictures.
        skip_brdf_lut(self.scene, {**self._sensors, **self._human_render_cameras})

    _setup_sensors.blank_brdf_lut = True
    BaseEnv._setup_sensors = _setup_sensors
    return True
