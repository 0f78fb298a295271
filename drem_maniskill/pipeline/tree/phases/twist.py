"""The twist phase: lineages that turn the held part about the end effector's own axes, from the backward seeds
nearest the goal (not in the paper).

Near the goal the backward loop's children move within the expert's small step, so the tree holds few states where the
part is near its goal pose but turned or tilted, and a reward trained on it values them arbitrarily: it may pay a part
turned at the opening like an insertion, and a policy then stops there. Each lineage starts at a backward seed of the
stretch of the path nearest the goal (``reach``) and keeps the child that turned farthest about one axis of the end
effector's frame at that seed (x, y and z, each way); step ``k`` is labelled the seed's depth plus ``k``, as the
backward loop labels a state ``k`` steps from its seed. A lineage whose best child turned less than ``min_turn`` of its
rotation range (``step`` of the controller's full rotation step) ends there, the part held by what surrounds it: going
on, it would label states like its seed ever farther. The phase reads the end effector's pose and the controller's
rotation step only, never the task's geometry.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
from mani_skill.utils.geometry.rotation_conversions import quaternion_to_matrix

from drem_maniskill.pipeline.tree.phases.base import (
    Phase,
    PhaseContext,
    full_range_rotation,
    grow_near_goal_lineages,
    origin_poses,
    rotation_vectors,
)
from drem_maniskill.utils.checks import check_fraction

AXES_PER_ORIGIN = 6  # +x, -x, +y, -y, +z, -z of the end effector's frame at the origin


@dataclass
class TwistConfig:
    """Settings of the twist phase."""

    depth: int = 0
    """Steps of every twist lineage (0: off)."""
    reach: float = 0.5
    """The lineages start at the backward seeds of this fraction of the depths to the start region, nearest the goal."""
    every: int = 2
    """Of those depths, every ``every``-th (from depth 1) starts lineages."""
    children: int = 16
    """Random actions per lineage and step: the rotation over its whole range (``step``), the translation within
    the backward loop's range at the lineage's origin."""
    min_turn: float = 0.25
    """A lineage ends when its best child turned less than this fraction of its rotation range."""
    step: float = 1.0
    """The children's rotation range as a fraction of the controller's full rotation step. Below 1 a lineage turns in
    finer steps, each labelled one more, so a part tilted a few degrees is labelled as many steps farther as the fine
    steps it took to get there."""

    def __post_init__(self):
        check_fraction("phases.twist.step", self.step, "the controller's rotation step")


def twist_axes(quaternions: np.ndarray) -> np.ndarray:
    """Unit rotation axes ``[origins * 6, 3]`` (world frame): each origin's end-effector x, y and z axes, each way.

    ``quaternions`` ``[origins, 4]`` (wxyz) are the end effector's orientations at the origins.
    """
    frames = quaternion_to_matrix(torch.as_tensor(quaternions, dtype=torch.float64)).numpy()  # columns: its axes
    axes = np.swapaxes(frames, 1, 2)  # rows: x, y, z
    return np.stack([axes, -axes], 2).reshape(-1, 3)


def sample_twist(ctx: PhaseContext, config: TwistConfig) -> None:
    """Lineage ``l`` keeps the child whose rotation from its origin goes farthest about its axis (``twist_axes``)."""
    origin_q = origin_poses(ctx, config.reach, config.every)[:, 3:7]
    axes, full = twist_axes(origin_q), ctx.config.action_scale * config.step
    origin_q = np.repeat(origin_q, AXES_PER_ORIGIN, axis=0)
    rotation, turn = ctx.sampler.rotation_dims, ctx.sampler.rotation_limit * full

    def turned(ee: np.ndarray, lineage: np.ndarray) -> np.ndarray:
        """Radians each child turned about its lineage's axis since the lineage's origin."""
        return np.einsum("nx,nx->n", rotation_vectors(ee[:, 3:7], origin_q[lineage]), axes[lineage])

    grow_near_goal_lineages(ctx, config, "twist", PHASE.counter, AXES_PER_ORIGIN, turned,
                            lambda scale: config.min_turn * turn,
                            shape=full_range_rotation(rotation, full))


PHASE = Phase(
    name="twist", config=TwistConfig, sample=sample_twist, size="depth", counter="twist_completed", growable=True,
    labels="the origin seed's depth + k at step k",
)
