"""The twist phase: lineages that turn the held part about the end effector's own axes, from the backward seeds
nearest the goal (not in the paper).

Near the goal the backward loop's children move within the expert's small step, so the tree holds few states where the
part is near its goal pose but turned or tilted, and a reward trained on it values them arbitrarily: it may pay a part
turned at the opening like an insertion, and a policy then stops there. Each lineage starts at a backward seed of the
half of the path nearest the goal and keeps the child that turned farthest about one axis of the end effector's frame
at that seed (x, y and z, each way); step ``k`` is labelled the seed's depth plus ``k``, as the backward loop labels a
state ``k`` steps from its seed. A lineage whose best child turned less than ``min_turn`` of a full rotation step (the
part held by what surrounds it) ends there: going on, it would label states like its seed ever farther. The phase reads
the end effector's pose and the controller's rotation step only, never the task's geometry.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import h5py
import numpy as np
import torch
from mani_skill.utils.geometry.rotation_conversions import quaternion_to_matrix

from drem_maniskill.pipeline.tree import tree_file
from drem_maniskill.pipeline.tree.phases.base import Phase, PhaseContext, farthest_along, rotation_vectors

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
    """Random actions per lineage and step: the rotation over the whole range, the translation within the backward
    loop's range at the lineage's origin."""
    min_turn: float = 0.25
    """A lineage ends when its best child turned less than this fraction of the controller's full rotation step."""


def twist_origin_depths(config: TwistConfig, start_depth: int) -> list:
    """The backward depths whose seeds start lineages: every ``every``-th of the first ``reach`` of the loop's."""
    return list(range(1, max(1, math.ceil(config.reach * start_depth)) + 1, config.every))


def twist_axes(quaternions: np.ndarray) -> np.ndarray:
    """Unit rotation axes ``[origins * 6, 3]`` (world frame): each origin's end-effector x, y and z axes, each way.

    ``quaternions`` ``[origins, 4]`` (wxyz) are the end effector's orientations at the origins.
    """
    frames = quaternion_to_matrix(torch.as_tensor(quaternions, dtype=torch.float64)).numpy()  # columns: its axes
    axes = np.swapaxes(frames, 1, 2)  # rows: x, y, z
    return np.stack([axes, -axes], 2).reshape(-1, 3)


def _lineages(ctx: PhaseContext, config: TwistConfig) -> tuple:
    """The live lineages' seeds, nodes, labels, indices and turns so far (about their axes), every lineage's origin
    orientation, and the steps done: their origins' at the start, else the last step's (``twist_<k>``)."""
    depths = twist_origin_depths(config, ctx.start_depth)
    with h5py.File(ctx.partial, "r") as f:
        done = int(f.attrs.get(PHASE.counter, 0))
        origin_nodes = np.array([int(f[f"seeds/depth_{d}/node"][0]) for d in depths])
        origin_q = f["tcp_pose"][()][origin_nodes, 3:7].astype(np.float64)
        if done == 0:
            seeds = [tree_file.read_seeds(f[f"seeds/depth_{d}"])[0][0] for d in depths]
            seeds = [s for s in seeds for _ in range(AXES_PER_ORIGIN)]
            nodes = list(np.repeat(origin_nodes, AXES_PER_ORIGIN))
            labels = np.repeat(depths, AXES_PER_ORIGIN)
            live = np.arange(len(seeds))
            turned = np.zeros(len(seeds))
        else:
            group = f[f"seeds/twist_{done}"]
            seeds, nodes = tree_file.read_seeds(group)
            labels, live = np.asarray(group.attrs["label"]), np.asarray(group.attrs["lineage"])
            turned = np.asarray(group.attrs["turned"])
    return seeds, nodes, labels, live, turned, np.repeat(origin_q, AXES_PER_ORIGIN, axis=0), done


def sample_twist(ctx: PhaseContext, config: TwistConfig) -> None:
    """Lineage ``l`` keeps the child whose rotation from its origin goes farthest about its axis (``twist_axes``);
    the live lineages, their labels and turns are kept on each step's seed group for a resume."""
    seeds, nodes, labels, live, turned, origin_q, done = _lineages(ctx, config)
    axes = twist_axes(origin_q[::AXES_PER_ORIGIN])
    rotation, full = ctx.sampler.rotation_dims, ctx.config.action_scale
    least = config.min_turn * ctx.sampler.rotation_limit * full

    def twist(actions: np.ndarray, scale: float) -> np.ndarray:
        """The rotation components over the whole range, the translation within ``scale``."""
        actions[:, rotation] = actions[:, rotation] / scale * full
        return actions

    bar = ctx.bar(config.depth, done, unit="step")
    for k in range(done, config.depth):
        if not len(live):
            break
        merged = {}
        # One range per origin depth: the backward loop's there, so a lineage moves as the loop's children did.
        for label in np.unique(labels):
            rows = np.flatnonzero(labels == label)
            part = ctx.children_of([seeds[i] for i in rows], [nodes[i] for i in rows], k * 1000 + int(label),
                                   config.children, ctx.backward_scale(int(label)), shape=twist)
            part["lineage"] = np.repeat(rows, config.children)
            merged = part if not merged else {key: np.concatenate([merged[key], part[key]]) for key in merged}
        order = np.argsort(merged.pop("lineage"), kind="stable")  # back to lineage order
        merged = {key: value[order] for key, value in merged.items()}
        about = rotation_vectors(merged["ee"][:, 3:7].astype(np.float64),
                                 np.repeat(origin_q[live], config.children, axis=0))
        chosen = farthest_along(about, np.zeros(3), axes[live])
        best = np.einsum("lx,lx->l", about[chosen], axes[live])
        labels = labels + 1
        goes_on = best - turned >= least
        chosen_kept = chosen[goes_on]
        nodes = tree_file.append_depth(
            ctx.partial, merged, np.repeat(labels, config.children), chosen_kept, group=f"twist_{k + 1}",
            counter=PHASE.counter, count=k + 1,
            attrs={"label": labels[goes_on], "lineage": live[goes_on], "turned": best[goes_on]})
        seeds = tree_file.seeds_at(merged, chosen_kept)
        labels, live, turned = labels[goes_on], live[goes_on], best[goes_on]
        bar.update(1)
    bar.close()


PHASE = Phase(
    name="twist", config=TwistConfig, sample=sample_twist, size="depth", counter="twist_completed", growable=True,
    labels="the origin seed's depth + k at step k",
)
