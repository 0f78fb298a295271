"""The push children: full-range random actions from every face and side seed (not in the paper; our tasks).

Lineage steps of a few millimetres press lightly (the face and side nodes read under 20 N at the wrist), so without
these children the only hard presses in a tree are the goal's children pushing on the opening's floor, and a reward
trained on it can pay a part pushed hard on the face or against the block's side like an insertion. These children
push the part into the face, the edge and the side with tens of newtons, labelled where they are: as far from the
goal as the seed they left, plus one. Those that fall into the opening are not kept: they may be a step from the
goal.
"""

from __future__ import annotations

from dataclasses import dataclass

import h5py
import numpy as np

from drem_maniskill.pipeline.tree import tree_file
from drem_maniskill.pipeline.tree.phases.base import Phase, PhaseContext, out_of_opening


@dataclass
class PushConfig:
    """Settings of the push children."""

    children: int = 0
    """Full-range random actions from every face and side seed (0: off)."""


def push_groups(config) -> list:
    """The seed groups (of a ``SamplerConfig``) the push children start from, in order: ``face_1`` .., ``side_1`` .."""
    face, side = config.phases["face"].depth, config.phases["side"].depth
    return [f"face_{k}" for k in range(1, face + 1)] + [f"side_{k}" for k in range(1, side + 1)]


def sample_push(ctx: PhaseContext, config: PushConfig) -> None:
    """Group ``i`` of ``push_groups`` gets seeds group ``push_<i + 1>`` (no seeds kept); ``push_completed`` counts the
    groups done, so an interrupted run resumes at the next group."""
    groups = push_groups(ctx.config)
    with h5py.File(ctx.partial, "r") as f:
        done = int(f.attrs.get(PHASE.counter, 0))
        if any(int(f.attrs.get(f"{g}_completed", 0)) < ctx.config.phases[g].depth for g in ("face", "side")):
            raise ValueError(f"{ctx.partial}: the push children start from the face and side seeds, which are not "
                             "complete")
    bar = ctx.bar(len(groups), done, unit="group")
    for i in range(done, len(groups)):
        with h5py.File(ctx.partial, "r") as f:
            seeds, nodes = tree_file.read_seeds(f[f"seeds/{groups[i]}"])
            depth = int(f["depth"][nodes[0]])
        merged = ctx.children_of(seeds, nodes, depth, config.children, ctx.config.action_scale)
        merged, _, dropped = out_of_opening(merged, np.zeros(0, np.int64), ctx.geometry)
        tree_file.append_depth(ctx.partial, merged, depth + 1, np.zeros(0, np.int64), group=f"push_{i + 1}",
                               counter=PHASE.counter, count=i + 1, attrs={"dropped_in_opening": dropped})
        bar.update(1)
    bar.close()


PHASE = Phase(
    name="push", config=PushConfig, sample=sample_push, size="children", counter="push_completed",
    needs_geometry=True, requires=("face",), growable=True, labels="one past the seed each child left; never seeds",
)
