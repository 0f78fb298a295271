"""The goal presses: random actions from the goal state pushing down over the whole range (not in the paper).

A demo that descends slowly ends as soon as the part is far enough in, before it reaches the opening's floor, and its
goal's children (small moves, ``expert_step_scale``) barely touch the floor, while a policy that inserts goes on
pushing: a tree without such presses puts a pressed insertion far from the goal. These children push the inserted part
down with up to the arm's full step, sideways and twisting within the goal's own children's range (full-range
sideways and twisting actions lever the part up and out of a tight opening): still inserted, one step from the goal.
"""

from __future__ import annotations

from dataclasses import dataclass

import h5py
import numpy as np

from drem_maniskill.pipeline.tree import tree_file
from drem_maniskill.pipeline.tree.phases.base import Phase, PhaseContext


@dataclass
class GoalPressConfig:
    """Settings of the goal presses."""

    count: int = 0
    """Random actions from the goal state pushing down (0: off)."""


def sample_goal_presses(ctx: PhaseContext, config: GoalPressConfig) -> None:
    """Written as one group, ``goal_press`` (no seeds kept); its counter is set once it is, so a resume skips it."""
    if tree_file.completed(ctx.partial, PHASE.counter):
        return
    with h5py.File(ctx.partial, "r") as f:
        seeds, nodes = tree_file.read_seeds(f["seeds/depth_0"])
    vertical, full = ctx.sampler.vertical_dim, ctx.config.action_scale

    def down(actions: np.ndarray, scale: float) -> np.ndarray:
        """The vertical component downwards over the whole range, the others within ``scale``."""
        actions[:, vertical] = -np.abs(actions[:, vertical]) / scale * full
        return actions

    merged = ctx.children_of(seeds, nodes, 0, config.count, ctx.backward_scale(0), shape=down)
    tree_file.append_depth(ctx.partial, merged, 1, np.zeros(0, np.int64), group="goal_press", counter=PHASE.counter,
                           count=1)


PHASE = Phase(
    name="goal_presses", config=GoalPressConfig, sample=sample_goal_presses, size="count",
    counter="goal_press_completed", growable=True,
    labels="1: a step from the goal; never seeds",
)
