"""A blank BRDF lookup table for cameras in scenes without an environment map.

SAPIEN's rasterizing shaders bind a BRDF lookup table (``samplerBRDFLUT``) for image-based specular light, and
SAPIEN computes it with a compute shader the first time a process renders: on a CPU Vulkan driver (lavapipe)
about 12 s of CPU in every process that renders, longer than most of what follows. The table only scales the
environment map's colour (``color * (fresnel * lut.x + lut.y)``), and a scene without an environment map samples
SAPIEN's black default cubemap, so there the term is zero whatever the table holds: a blank table gives the same
images bit for bit (``tests/envs/test_rendering.py``) without the computation.
"""

from __future__ import annotations

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
