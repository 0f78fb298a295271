"""The slide phase: lineages that move the held part sideways, across its approach, from the backward seeds nearest the
goal (not in the paper).

Near the goal the backward loop's children stay within the expert's small step of its path, so the tree holds few
states where the part is near the goal but beside it (pressed on the socket's face a few millimetres off the opening,
or hovering beside it), and a reward trained on them values those states arbitrarily. Each lineage starts at a backward
seed of the stretch of the path nearest the goal (``reach``) and keeps the child that went farthest from it along one
direction across the approach (``lineages`` of them, spread evenly around it), its children drawn within ``step`` of the
loop's range there; step ``k`` is labelled the seed's depth plus ``k``. The approach is the direction the backward seeds
moved in, from the seed of the last depth in ``approach_reach`` (or ``reach``) to the goal. A lineage whose best child
moved less than ``min_move`` of the step range along its direction (the part held by what surrounds it) ends there.
The phase reads the tree's own end-effector positions only, never the task's geometry.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Optional

import h5py
import numpy as np

from drem_maniskill.pipeline.tree.phases.base import (
    Phase,
    PhaseContext,
    grow_near_goal_lineages,
    near_goal_last,
    origin_poses,
)
from drem_maniskill.utils.checks import check_fraction


@dataclass
class SlideConfig:
    """Settings of the slide phase."""

    depth: int = 0
    """Steps of every slide lineage (0: off)."""
    lineages: int = 8
    """Directions per origin, across the approach, spread evenly around it."""
    reach: float = 0.5
    """The lineages start at the backward seeds of this fraction of the depths to the start region, nearest the goal."""
    approach_reach: Optional[float] = None
    """The approach runs from the backward seed at this fraction of the depths to the start region to the goal (None:
    ``reach``). Lineages from farther up the path (``reach`` above it) still move across the final approach, not
    across the way the demo came in from the start region."""
    every: int = 2
    """Of those depths, every ``every``-th (from depth 1) starts lineages."""
    children: int = 16
    """Random actions per lineage and step, within the backward loop's range at the lineage's origin."""
    min_move: float = 0.25
    """A lineage ends when its best child moved less than this fraction of its step range along its direction."""
    step: float = 1.0
    """The children's action range as a fraction of the backward loop's range at the lineage's origin. Below 1 a
    lineage leaves the path in finer steps, each labelled one more, so a part a few millimetres beside the path is
    labelled as many steps farther as the fine steps it took to get there."""

    def __post_init__(self):
        check_fraction("phases.slide.approach_reach", self.approach_reach, "the backward loop's depths", optional=True)
        check_fraction("phases.slide.step", self.step, "the backward loop's range")


def across_basis(approach: np.ndarray) -> tuple:
    """Two orthonormal vectors ``(u, v)`` [3] across the unit vector ``approach``."""
    helper = np.eye(3)[np.argmin(np.abs(approach))]  # the world axis farthest from the approach
    u = np.cross(approach, helper)
    u /= np.linalg.norm(u)
    return u, np.cross(approach, u)


def slide_directions(approach: np.ndarray, count: int) -> np.ndarray:
    """Unit vectors ``[count, 3]`` across the unit vector ``approach``, spread evenly around it."""
    u, v = across_basis(approach)
    angle = 2 * np.pi * np.arange(count) / count
    return np.cos(angle)[:, None] * u + np.sin(angle)[:, None] * v


def approach_of(path, reach: float, start_depth: int) -> np.ndarray:
    """The unit direction the backward seeds move in towards the goal over the first ``reach`` of the loop's depths."""
    last = near_goal_last(reach, start_depth)
    with h5py.File(path, "r") as f:
        tcp = f["tcp_pose"][()][[int(f[f"seeds/depth_{d}/node"][0]) for d in (last, 0)], :3].astype(np.float64)
    approach = tcp[1] - tcp[0]
    norm = np.linalg.norm(approach)
    if norm < 1e-6:
        raise ValueError(f"{path}: the backward seeds at depths {last} and 0 share a position, so the slide phase has "
                         "no approach to move across; raise its reach")
    return approach / norm


def sample_slide(ctx: PhaseContext, config: SlideConfig) -> None:
    """Lineage ``l`` keeps the child that went farthest from its origin along its direction (``slide_directions``)."""
    origin = np.repeat(origin_poses(ctx, config.reach, config.every)[:, :3], config.lineages, axis=0)
    approach = approach_of(ctx.partial, config.reach if config.approach_reach is None else config.approach_reach,
                           ctx.start_depth)
    directions = np.tile(slide_directions(approach, config.lineages), (len(origin) // config.lineages, 1))
    limit = ctx.sampler.translation_limit

    def moved(ee: np.ndarray, lineage: np.ndarray) -> np.ndarray:
        """Metres each child went along its lineage's direction from the lineage's origin."""
        return np.einsum("nx,nx->n", ee[:, :3] - origin[lineage], directions[lineage])

    grow_near_goal_lineages(ctx, config, "slide", PHASE.counter, config.lineages, moved,
                            lambda scale: config.min_move * scale * limit, range_scale=config.step)


PHASE = Phase(
    name="slide", config=SlideConfig, sample=sample_slide, size="depth", counter="slide_completed", growable=True,
    labels="the origin seed's depth + k at step k",
)
