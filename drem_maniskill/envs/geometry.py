"""Collision geometry built from boxes and convex prisms, so it runs on CPU and GPU PhysX."""

from __future__ import annotations

import numpy as np
import sapien

from drem_maniskill.utils.cache import cached_text_file


def z_rotation(angle: float) -> list[float]:
    """Quaternion (wxyz) of a rotation by ``angle`` about z."""
    return [float(np.cos(angle / 2)), 0.0, 0.0, float(np.sin(angle / 2))]


def prism_obj(radius: float, length: float, segments: int) -> str:
    """OBJ file of a regular prism along z from 0 to ``length``, vertices on ``radius``."""
    angles = 2 * np.pi * np.arange(segments) / segments
    lines = []
    for z in (0.0, length):
        lines += [f"v {radius * np.cos(a):.7f} {radius * np.sin(a):.7f} {z:.7f}" for a in angles]
    bottom = " ".join(str(i + 1) for i in reversed(range(segments)))
    top = " ".join(str(segments + i + 1) for i in range(segments))
    lines += [f"f {bottom}", f"f {top}"]
    for i in range(segments):
        j = (i + 1) % segments
        lines.append(f"f {i + 1} {j + 1} {segments + j + 1} {segments + i + 1}")
    return cached_text_file(f"prism_r{radius:.5f}_l{length:.4f}_n{segments}", ".obj", "\n".join(lines) + "\n")


def add_round_bore(builder, inner_radius: float, depth: float, wall: float, segments: int, z0: float, material):
    """Add a ring of ``segments`` boxes whose inner faces are tangent to ``inner_radius``.

    The bore is then a regular ``segments``-gon with in-radius ``inner_radius``: it is never
    narrower than the nominal circle and at most ``inner_radius * (1/cos(pi/segments) - 1)``
    wider (in its corners). The boxes are as wide as their outer edge needs, so they overlap
    outside the bore and leave no gaps.
    """
    half_tangent = (inner_radius + wall) * np.tan(np.pi / segments)
    half = [wall / 2, half_tangent, depth / 2]
    for k in range(segments):
        angle = 2 * np.pi * k / segments
        r = inner_radius + wall / 2
        pose = sapien.Pose([r * np.cos(angle), r * np.sin(angle), z0 + depth / 2], z_rotation(angle))
        builder.add_box_collision(pose, half)
        builder.add_box_visual(pose, half, material=material)
