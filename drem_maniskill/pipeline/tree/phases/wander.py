"""The wander phase: lineages that move the held part across its approach and turn it at once, each along its own
direction in the joint space of the two (not in the paper).

The slide and twist phases each move the part one way only, so the tree holds parts beside the path or turned on it,
not both: a part a few millimetres beside the opening, tilted and turned a little, is a state no lineage made, and a
reward trained on such a tree may pay it like an insertion. Each wander lineage starts at a backward seed of ``reach``
of the loop's depths and keeps the child that went farthest along its direction: a unit vector of five components, two
across the approach (``slide.approach_of``) and three about the end effector's own axes at the origin, each in units of
the lineage's step range there (``step`` of the backward loop's translation range, ``turn_step`` of the controller's
rotation step). The directions are drawn once from the sampler's seed and shared by every origin. Step ``k`` is
labelled the seed's depth plus ``k``; a lineage whose best child gained less than ``min_move`` of a step ends there.
The phase reads the tree's own end-effector poses and the controller's steps only, never the task's geometry.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Optional

import numpy as np
import torch
from mani_skill.utils.geometry.rotation_conversions import quaternion_to_matrix

from drem_maniskill.pipeline.tree.phases.base import (
    Phase,
    PhaseContext,
    full_range_rotation,
    grow_near_goal_lineages,
    near_goal_depths,
    origin_poses,
    rotation_vectors,
)
from drem_maniskill.pipeline.tree.phases.slide import across_basis, approach_of
from drem_maniskill.utils.checks import check_fraction


@dataclass
class WanderConfig:
    """Settings of the wander phase."""

    depth: int = 0
    """Steps of every wander lineage (0: off)."""
    lineages: int = 16
    """Directions per origin, drawn at random in the five dimensions of sliding and turning."""
    reach: float = 1.0
    """The lineages start at the backward seeds of this fraction of the depths to the start region, nearest the goal."""
    approach_reach: Optional[float] = 0.5
    """The approach the lineages move across runs from the backward seed at this fraction of the depths to the start
    region to the goal (None: ``reach``)."""
    every: int = 4
    """Of those depths, every ``every``-th (from depth 1) starts lineages."""
    children: int = 16
    """Random actions per lineage and step."""
    min_move: float = 0.25
    """A lineage ends when its best child gained less than this fraction of a step along its direction."""
    step: float = 0.1
    """The children's translation range as a fraction of the backward loop's range at the lineage's origin."""
    turn_step: float = 0.25
    """The children's rotation range as a fraction of the controller's full rotation step."""

    def __post_init__(self):
        check_fraction("phases.wander.approach_reach", self.approach_reach, "the backward loop's depths",
                       optional=True)
        check_fraction("phases.wander.step", self.step, "the backward loop's range")
        check_fraction("phases.wander.turn_step", self.turn_step, "the controller's rotation step")


def wander_directions(count: int, seed: int) -> np.ndarray:
    """Unit vectors ``[count, 5]`` drawn uniformly on the sphere: two slide components, then three turn components."""
    directions = np.random.default_rng([seed, 0x77616E64]).normal(size=(count, 5))
    return directions / np.linalg.norm(directions, axis=1, keepdims=True)


def wander_axes(quaternions: np.ndarray, approach: np.ndarray, directions: np.ndarray) -> tuple:
    """The world-frame slide vectors and rotation axes ``([origins * count, 3], [origins * count, 3])`` of each
    origin's lineages: ``directions`` ``[count, 5]`` read in the plane across ``approach`` and in the end effector's
    frame at the origin (``quaternions`` ``[origins, 4]``, wxyz)."""
    u, v = across_basis(approach)
    slide = directions[:, :1] * u + directions[:, 1:2] * v
    frames = quaternion_to_matrix(torch.as_tensor(quaternions, dtype=torch.float64)).numpy()  # columns: its axes
    turn = np.einsum("oxa,la->olx", frames, directions[:, 2:]).reshape(-1, 3)
    return np.tile(slide, (len(quaternions), 1)), turn


def sample_wander(ctx: PhaseContext, config: WanderConfig) -> None:
    """Lineage ``l`` keeps the child that went farthest, in step units, along its five-dimensional direction."""
    origin = origin_poses(ctx, config.reach, config.every)
    approach = approach_of(ctx.partial, config.reach if config.approach_reach is None else config.approach_reach,
                           ctx.start_depth)
    slide, turn = wander_axes(origin[:, 3:7], approach, wander_directions(config.lineages, ctx.config.seed))
    origin = np.repeat(origin, config.lineages, axis=0)
    full = ctx.config.action_scale * config.turn_step
    # One step's reach each way: the translation range at the lineage's origin depth, the rotation range everywhere.
    ranges = [ctx.backward_scale(d) for d in near_goal_depths(config.reach, config.every, ctx.start_depth)]
    metres = np.repeat(ranges, config.lineages) * config.step * ctx.sampler.translation_limit
    radians = ctx.sampler.rotation_limit * full

    def gained(ee: np.ndarray, lineage: np.ndarray) -> np.ndarray:
        """Steps each child went along its lineage's direction since the lineage's origin."""
        moved = np.einsum("nx,nx->n", ee[:, :3] - origin[lineage, :3], slide[lineage]) / metres[lineage]
        turned = np.einsum("nx,nx->n", rotation_vectors(ee[:, 3:7], origin[lineage, 3:7]), turn[lineage]) / radians
        return moved + turned

    grow_near_goal_lineages(ctx, config, "wander", PHASE.counter, config.lineages, gained,
                            lambda scale: config.min_move, shape=full_range_rotation(ctx.sampler.rotation_dims, full),
                            range_scale=config.step)


PHASE = Phase(
    name="wander", config=WanderConfig, sample=sample_wander, size="depth", counter="wander_completed", growable=True,
    labels="the origin seed's depth + k at step k",
)
