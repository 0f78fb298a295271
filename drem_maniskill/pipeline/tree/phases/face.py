"""The face and side phases: lineages that slide the part from the opening over the socket's face, then over the
face's edge and down beside the socket's block (not in the paper; our insertion tasks).

The backward loop's children of the seed at the opening land anywhere on the face within a random action of it, all
one depth from that seed, so the reward learns no lead along the face to the opening. Each face lineage starts at that
seed (the entry, ``tree_file.face_entry_depth``) and keeps the child that slid farthest along its own direction,
pressing on the face a few millimetres per depth. No other phase reaches the part lowered along the block's side,
where a policy would find a reward that values it arbitrarily: the side lineages go on from the face lineages' last
seeds, steeply down.

The child kept is the one farthest along the lineage's direction, less ``rotation_weight`` metres per radian it
turned (the part stays upright), and out of the opening (``caught_penalty``). Children that went into the opening are
near the goal, not where their lineage is: they are not kept (``out_of_opening``; counted in each seeds group's
``dropped_in_opening``).
"""

from __future__ import annotations

from dataclasses import dataclass

import h5py
import numpy as np

from drem_maniskill.pipeline.tree import tree_file
from drem_maniskill.pipeline.tree.phases.base import (
    Phase,
    PhaseContext,
    caught_penalty,
    directions_at,
    farthest_along,
    out_of_opening,
    rotation_from,
)


@dataclass
class FaceConfig:
    """Settings of the face phase."""

    depth: int = 0
    """Steps of every face lineage (0: off)."""
    lineages: int = 8
    """Face directions: azimuths spread evenly, all at ``elevation``."""
    children: int = 60
    """Random actions per face seed and step."""
    step: float = 0.0015
    """Metres of end-effector travel the arm actions span (the farthest child moves about this far)."""
    elevation: float = -30.0
    """Degrees above the horizontal of the face directions (negative: pressing down on the face as it slides)."""


@dataclass
class SideConfig:
    """Settings of the side phase (it continues the face lineages, one per face direction)."""

    depth: int = 0
    """Steps of every side lineage (0: off)."""
    children: int = 60
    """Random actions per side seed and step."""
    step: float = 0.004
    """Metres of end-effector travel the arm actions span."""
    elevation: float = -60.0
    """Degrees above the horizontal of the side directions (steeply down, over the edge and along the side)."""


def face_directions(face: FaceConfig, elevation_deg=None) -> np.ndarray:
    """Unit vectors ``[face.lineages, 3]`` (world frame at the expert's placement) the face lineages slide along (at
    ``elevation_deg``, default ``face.elevation``; the side lineages' at the side phase's)."""
    return directions_at(face.lineages, face.elevation if elevation_deg is None else elevation_deg)


def _lineages(ctx: PhaseContext, phase: Phase, total: int, children: int, step: float, directions: np.ndarray,
              first: str, label0: int, side: bool) -> None:
    """Steps ``done + 1 .. total`` of ``phase``'s lineages along ``directions`` (``done``: its counter), from the seeds
    of group ``first``; step ``k``'s nodes labelled ``label0 + k``."""
    entry = tree_file.face_entry_depth(ctx.partial, ctx.start_depth)
    name, counter = phase.name, phase.counter
    with h5py.File(ctx.partial, "r") as f:
        done = int(f.attrs.get(counter, 0))
        seeds, nodes = tree_file.read_seeds(f[f"seeds/{first}"] if done == 0 else f[f"seeds/{name}_{done}"])
        entry_pose = f["tcp_pose"][int(f[f"seeds/depth_{entry}/node"][0])].astype(np.float64)
    if done == 0 and not side:
        seeds, nodes = seeds[:1] * len(directions), nodes[:1] * len(directions)
    scale = ctx.scale_for(step)
    bar = ctx.bar(total, done)
    for k in range(done, total):
        merged = ctx.children_of(seeds, nodes, label0 + k, children, scale)
        penalty = ctx.config.rotation_weight * rotation_from(merged["ee"][:, 3:7].astype(np.float64), entry_pose[3:7])
        penalty += caught_penalty(merged["tip_in_socket"].astype(np.float64), ctx.geometry, side)
        chosen = farthest_along(merged["ee"], entry_pose[:3], directions, penalty)
        merged, chosen, dropped = out_of_opening(merged, chosen, ctx.geometry)
        nodes = tree_file.append_depth(ctx.partial, merged, label0 + k + 1, chosen, group=f"{name}_{k + 1}",
                                       counter=counter, count=k + 1, attrs={"dropped_in_opening": dropped})
        seeds = tree_file.seeds_at(merged, chosen)
        bar.update(1)
    bar.close()


def sample_face(ctx: PhaseContext, config: FaceConfig) -> None:
    """Face lineages from the entry seed; step ``k`` labelled ``entry + k``: ``k`` small moves from the seed at the
    opening, which is ``entry`` from the goal."""
    entry = tree_file.face_entry_depth(ctx.partial, ctx.start_depth)
    _lineages(ctx, FACE, config.depth, config.children, config.step, face_directions(config), f"depth_{entry}", entry,
              side=False)


def sample_side(ctx: PhaseContext, config: SideConfig) -> None:
    """Side lineages from the face lineages' last seeds; step ``k`` labelled ``entry + face depth + k``: farther from
    the goal than the face they left."""
    face = ctx.config.phases["face"]
    if tree_file.completed(ctx.partial, FACE.counter) < face.depth:
        raise ValueError(f"{ctx.partial}: the side phase starts where the face phase ended, which is not complete")
    entry = tree_file.face_entry_depth(ctx.partial, ctx.start_depth)
    _lineages(ctx, SIDE, config.depth, config.children, config.step, face_directions(face, config.elevation),
              f"face_{face.depth}", entry + face.depth, side=True)


FACE = Phase(
    name="face", config=FaceConfig, sample=sample_face, size="depth", counter="face_completed", needs_geometry=True,
    labels="entry + k at step k, where entry is the backward depth at which the part leaves the opening",
)
SIDE = Phase(
    name="side", config=SideConfig, sample=sample_side, size="depth", counter="side_completed", needs_geometry=True,
    requires=("face",), growable=True, labels="entry + face depth + k at step k",
)
