"""Collision geometry built from boxes and convex prisms, so it runs on CPU and GPU PhysX."""

from __future__ import annotations

import numpy as np
import sapien

from drem_maniskill.utils.cache import cached_text_file


def z_rotation(angle: float) -> list[float]:
    """Quaternion (wxyz) of a rotation by ``angle`` about z."""
    return [float(np.cos(angle / 2)), 0.0, 0.0, float(np.sin(angle / 2))]


def y_rotation(angle: float) -> list[float]:
    """Quaternion (wxyz) of a rotation by ``angle`` about y."""
    return [float(np.cos(angle / 2)), 0.0, float(np.sin(angle / 2)), 0.0]


def polygon_prism_obj(name: str, xy: np.ndarray, length: float) -> str:
    """OBJ file of a prism along z from 0 to ``length`` over the convex polygon ``xy`` ``[N, 2]`` (anticlockwise)."""
    n = len(xy)
    lines = []
    for z in (0.0, length):
        lines += [f"v {x:.7f} {y:.7f} {z:.7f}" for x, y in xy]
    bottom = " ".join(str(i + 1) for i in reversed(range(n)))
    top = " ".join(str(n + i + 1) for i in range(n))
    lines += [f"f {bottom}", f"f {top}"]
    for i in range(n):
        j = (i + 1) % n
        lines.append(f"f {i + 1} {j + 1} {n + j + 1} {n + i + 1}")
    return cached_text_file(name, ".obj", "\n".join(lines) + "\n")


def prism_obj(radius: float, length: float, segments: int) -> str:
    """OBJ file of a regular prism along z from 0 to ``length``, vertices on ``radius`` (the first on +x)."""
    angles = 2 * np.pi * np.arange(segments) / segments
    xy = radius * np.stack([np.cos(angles), np.sin(angles)], axis=1)
    return polygon_prism_obj(f"prism_r{radius:.5f}_l{length:.4f}_n{segments}", xy, length)


def d_prism_obj(radius: float, flat: float, length: float, segments: int = 32) -> str:
    """OBJ file of a D-shaped prism along z: a round of ``radius`` cut by a flat at x = ``flat``."""
    half_chord = float(np.sqrt(radius**2 - flat**2))
    edge = float(np.arctan2(half_chord, flat))  # the flat's ends, at angles +-edge
    angles = np.linspace(edge, 2 * np.pi - edge, segments)
    xy = radius * np.stack([np.cos(angles), np.sin(angles)], axis=1)  # the round, counter-clockwise; the flat closes it
    return polygon_prism_obj(f"dprism_r{radius:.5f}_f{flat:.5f}_l{length:.4f}_n{segments}", xy, length)


def add_round_bore(builder, inner_radius: float, depth: float, wall: float, segments: int, z0: float, material,
                   phase: float = 0.0):
    """Add a ring of ``segments`` boxes whose inner faces are tangent to ``inner_radius``.

    The bore is then a regular ``segments``-gon with in-radius ``inner_radius`` whose first face's normal points
    along ``phase`` (rad from +x): it is never narrower than the nominal circle and at most
    ``inner_radius * (1/cos(pi/segments) - 1)`` wider (in its corners). The boxes are as wide as their outer edge
    needs, so they overlap outside the bore and leave no gaps. Few segments give a polygonal bore (a square or a
    hexagonal hole) for a prism of the same sides.
    """
    half_tangent = (inner_radius + wall) * np.tan(np.pi / segments)
    half = [wall / 2, half_tangent, depth / 2]
    for k in range(segments):
        angle = phase + 2 * np.pi * k / segments
        r = inner_radius + wall / 2
        pose = sapien.Pose([r * np.cos(angle), r * np.sin(angle), z0 + depth / 2], z_rotation(angle))
        builder.add_box_collision(pose, half)
        builder.add_box_visual(pose, half, material=material)


def add_block_with_bore(builder, inner_radius: float, sides: int, depth: float, wall: float, base: float, material,
                        phase: float = 0.0) -> float:
    """A socket block: a base plate ``base`` thick, a ``sides``-gon bore ``depth`` deep on it; its half-width."""
    outer = inner_radius + wall
    half = [outer, outer, base / 2]
    builder.add_box_collision(sapien.Pose([0, 0, base / 2]), half)
    builder.add_box_visual(sapien.Pose([0, 0, base / 2]), half, material=material)
    add_round_bore(builder, inner_radius, depth, wall, sides, base, material, phase)
    return outer


class PosedBuilder:
    """An actor builder whose boxes sit at ``pose`` times the pose they are given (a tilted socket's block)."""

    def __init__(self, builder, pose: sapien.Pose):
        self._builder = builder
        self._pose = pose

    def add_box_collision(self, pose: sapien.Pose, half_size, **kwargs):
        """The builder's ``add_box_collision`` at ``pose`` in the posed frame."""
        return self._builder.add_box_collision(self._pose * pose, half_size, **kwargs)

    def add_box_visual(self, pose: sapien.Pose, half_size, **kwargs):
        """The builder's ``add_box_visual`` at ``pose`` in the posed frame."""
        return self._builder.add_box_visual(self._pose * pose, half_size, **kwargs)
