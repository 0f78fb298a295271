"""The turn phase: lineages that turn the part about its axis and tilt it, near the opening (not in the paper).

Every other phase keeps the part upright there (the face and side lineages penalise turning, the backward loop's
steps near the goal are a fraction of the rotation range), so a reward trained on them values a turned part near the
opening arbitrarily, and may pay a part hovering off the axis, turned far, almost as an insertion. Each
lineage starts at a seed near the opening (``HOVER_DEPTHS`` above it, ``FACE_STEPS`` along the face lineages) and
keeps the child that turned farthest about its own axis, out of the opening; children that went into the opening are
not kept. Step ``k`` is labelled the lineage's first label plus ``k``: one step per rotation step of the controller.
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
    farthest_along,
    full_range_rotation,
    out_of_opening,
    rotation_vectors,
)

HOVER_DEPTHS = (0, 2, 4)  # the lineages start at the backward seeds this many depths past the entry (above it)
FACE_STEPS = (2, 5)  # and at these steps of every face lineage (3 and 7.5 mm from the opening at 1.5 mm a step)
GOLDEN = 0.381966  # turns of azimuth between the tilts of successive origins: many tilts, none repeated


@dataclass
class TurnConfig:
    """Settings of the turn phase (its translation span is the face phase's ``step``)."""

    depth: int = 0
    """Steps of every turn lineage (0: off)."""
    lineages: int = 2
    """Turn lineages per origin: rotation axes ``tilt`` from the vertical, turning one way and the other."""
    children: int = 24
    """Random actions per turn seed and step: the rotation over the whole range, the translation within face.step."""
    tilt: float = 20.0
    """Degrees between a lineage's rotation axis and the vertical: mostly turning about the part's axis."""


def turn_axes(config: TurnConfig, origins: int) -> np.ndarray:
    """Unit rotation axes ``[origins * lineages, 3]`` (world frame at the expert's placement) of the turn lineages.

    Lineage ``l`` of origin ``o``: ``tilt`` from the vertical, turning about +z for even ``l`` and -z for odd, tilting
    towards an azimuth that differs between origins (golden-angle steps), so the tree sees many tilts.
    """
    lineages = np.arange(origins * config.lineages)
    azimuth = 2 * np.pi * (lineages // config.lineages * GOLDEN + lineages % config.lineages / config.lineages)
    tilt = np.deg2rad(config.tilt)
    sign = np.where(lineages % 2 == 0, 1.0, -1.0)
    return np.stack([np.sin(tilt) * np.cos(azimuth), np.sin(tilt) * np.sin(azimuth), sign * np.cos(tilt)], -1)


def turn_origins(path, config, start_depth: int) -> list:
    """The turn lineages' first seeds (of a ``SamplerConfig``'s tree at ``path``): ``(group of seeds/, index in it,
    label)`` each: the entry seed, the backward seeds ``HOVER_DEPTHS`` past it that are out of the opening, and the
    face lineages' seeds at ``FACE_STEPS``."""
    entry = tree_file.face_entry_depth(path, start_depth)
    face = config.phases["face"]
    with h5py.File(path, "r") as f:
        geometry = tree_file.tree_geometry(f)
        # Above the opening: a backward seed past the entry may have gone back into it (a coarse tree's).
        hover = [d for d in HOVER_DEPTHS if entry + d <= start_depth and (d == 0 or not geometry.in_opening(
            f["tip_in_socket"][[int(f[f"seeds/depth_{entry + d}/node"][0])]])[0])]
    groups = [(f"depth_{entry + d}", 0, entry + d) for d in hover]
    groups += [(f"face_{k}", i, entry + k) for k in FACE_STEPS if k <= face.depth for i in range(face.lineages)]
    return groups


def _first_seeds(ctx: PhaseContext, config: TurnConfig) -> tuple:
    """The lineages' seeds, nodes and labels to go on from (their origins', or the last step done's), their origins'
    orientations, the number of origins and the steps done."""
    with h5py.File(ctx.partial, "r") as f:
        if int(f.attrs.get("face_completed", 0)) < ctx.config.phases["face"].depth:
            raise ValueError(f"{ctx.partial}: the turn phase starts from the face seeds, which are not complete")
        done = int(f.attrs.get(PHASE.counter, 0))
        origins = turn_origins(ctx.partial, ctx.config, ctx.start_depth)
        first = [f[f"seeds/{g}"] for g, _, _ in origins]
        start_nodes = np.array([int(g["node"][i]) for g, (_, i, _) in zip(first, origins)])
        start_q = f["tcp_pose"][()][np.repeat(start_nodes, config.lineages), 3:7].astype(np.float64)
        if done == 0:
            seeds = [tree_file.seeds_at(g, [i])[0] for g, (_, i, _) in zip(first, origins)]
            seeds = [s for s in seeds for _ in range(config.lineages)]
            nodes = list(np.repeat(start_nodes, config.lineages))
            labels = np.repeat([label for _, _, label in origins], config.lineages)
        else:
            seeds, nodes = tree_file.read_seeds(f[f"seeds/turn_{done}"])
            labels = np.asarray(f[f"seeds/turn_{done}"].attrs["label"])
    return seeds, nodes, labels, start_q, len(origins), done


def sample_turn(ctx: PhaseContext, config: TurnConfig) -> None:
    """Lineage ``l`` keeps the child whose rotation from its first seed goes farthest along its axis (``turn_axes``),
    out of the opening; step ``k``'s labels are kept per seed in the group's ``label`` attribute for a resume."""
    seeds, nodes, labels, start_q, origins, done = _first_seeds(ctx, config)
    axes = turn_axes(config, origins)
    rotation, full = ctx.sampler.rotation_dims, ctx.config.action_scale

    scale = ctx.scale_for(ctx.config.phases["face"].step)
    bar = ctx.bar(config.depth, done)
    for k in range(done, config.depth):
        merged = ctx.children_of(seeds, nodes, int(labels.min()), config.children, scale,
                                   shape=full_range_rotation(rotation, full))
        turned = rotation_vectors(merged["ee"][:, 3:7].astype(np.float64),
                                  np.repeat(start_q, config.children, axis=0))
        # As the other lineages go farthest along a direction in space, these go farthest about their axes.
        penalty = caught_penalty(merged["tip_in_socket"].astype(np.float64), ctx.geometry, side=True)
        chosen = farthest_along(turned, np.zeros(3), axes, penalty)
        merged["label"] = np.repeat(labels + 1, config.children)
        merged, chosen, dropped = out_of_opening(merged, chosen, ctx.geometry)
        labels = labels + 1
        nodes = tree_file.append_depth(ctx.partial, merged, merged.pop("label"), chosen, group=f"turn_{k + 1}",
                                       counter=PHASE.counter, count=k + 1,
                                       attrs={"dropped_in_opening": dropped, "label": labels})
        seeds = tree_file.seeds_at(merged, chosen)
        bar.update(1)
    bar.close()


PHASE = Phase(
    name="turn", config=TurnConfig, sample=sample_turn, size="depth", counter="turn_completed", needs_geometry=True,
    requires=("face",), growable=True, labels="the lineage's first seed's label + k at step k",
)
