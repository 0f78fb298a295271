"""The outward phase: lineages leaving the start region, away from the expert's path (not in the paper).

The paper's tree is a tube around the expert, so a reward trained on it values states off the tube arbitrarily: a
policy can find one it is paid for like an insertion (the part pressed on the floor beside the socket). Each outward
lineage starts at the start-region seed and keeps the child that went farthest along its own direction, so the tree
gains states beside and below the start region, labelled by their depth: farther from the goal than the start.
"""

from __future__ import annotations

from dataclasses import dataclass

import h5py
import numpy as np

from drem_maniskill.pipeline.tree import tree_file
from drem_maniskill.pipeline.tree.phases.base import Phase, PhaseContext, directions_at, farthest_along


@dataclass
class OutwardConfig:
    """Settings of the outward phase."""

    depth: int = 0
    """Depths sampled past the start region (0: off)."""
    lineages: int = 12
    """Outward directions: azimuths spread evenly, elevations alternating over ``elevations``."""
    children: int = 100
    """Random actions (full range) per outward seed and depth."""
    elevations: tuple = (0.0, -35.0, -60.0)
    """Degrees above the horizontal of the outward directions (negative: downwards, towards the floor)."""


def outward_directions(config: OutwardConfig) -> np.ndarray:
    """Unit vectors ``[lineages, 3]`` (world frame at the expert's placement) the outward lineages move along."""
    return directions_at(config.lineages, config.elevations)


def sample_outward(ctx: PhaseContext, config: OutwardConfig) -> None:
    """One lineage per direction from the start-region seed, going on from the tree's last complete depth."""
    directions = outward_directions(config)
    start = ctx.start_depth
    with h5py.File(ctx.partial, "r") as f:
        origin = f["tcp_pose"][int(f[f"seeds/depth_{start}/node"][0])][:3].astype(np.float64)
        depth = int(f.attrs["completed_depth"])
        seeds, nodes = tree_file.read_seeds(f[f"seeds/depth_{depth}"])
    if depth == start:
        seeds, nodes = seeds[:1] * len(directions), nodes[:1] * len(directions)
    bar = ctx.bar(config.depth, depth - start)
    while depth < start + config.depth:
        merged = ctx.children_of(seeds, nodes, depth, config.children, ctx.config.action_scale)
        chosen = farthest_along(merged["ee"], origin, directions)
        depth += 1
        nodes = tree_file.append_depth(ctx.partial, merged, depth, chosen)
        seeds = tree_file.seeds_at(merged, chosen)
        bar.update(1)
    bar.close()


PHASE = Phase(
    name="outward", config=OutwardConfig, sample=sample_outward, size="depth", counter="completed_depth",
    labels="the depth past the goal, as the backward loop's: start_depth + k at step k",
)
