"""What an extra phase of backward sampling is (``Phase``), what it is given (``PhaseContext``), and the lineage
helpers the phases share."""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, Callable, Optional

import h5py
import numpy as np
import torch
from mani_skill.utils.geometry.rotation_conversions import (
    quaternion_invert,
    quaternion_multiply,
    quaternion_to_axis_angle,
)

from drem_maniskill.envs.adapter import SocketGeometry
from drem_maniskill.pipeline.tree import tree_file
from drem_maniskill.pipeline.tree.child_sampler import ActionShape, ChildPool, ChildSampler
from drem_maniskill.utils.progress import progress_bar


@dataclass(frozen=True)
class Phase:
    """One named extra phase: its settings, its sampling function, how it labels and how it resumes."""

    name: str
    """Its key in ``SamplerConfig.phases`` and in recipes."""
    config: type
    """Its settings: a dataclass whose fields all have defaults."""
    sample: Callable[["PhaseContext", Any], None]
    """Samples the phase into the partial tree file, going on from its completion counter."""
    size: str
    """The settings field that turns it on: the phase runs when it is above 0."""
    counter: str
    """The tree file's attribute counting its completed steps (its resume point)."""
    labels: str
    """How its nodes are labelled (their ``depth``), in a line."""
    requires: tuple = ()
    """Phases whose seeds it starts from: they must be on too, and run before it."""
    needs_geometry: bool = False
    """Whether it needs the task's socket geometry (``EnvAdapter.socket_geometry``)."""
    growable: bool = False
    """Whether a finished tree can gain it by a resume; once begun, it resumes only with the same settings."""

    def switch(self) -> str:
        """Where its size is set: the recipe key and the command-line flag."""
        return f"phases.{self.name}.{self.size}, --phase {self.name}.{self.size}=N"

    def is_on(self, settings) -> bool:
        """Whether ``settings`` (its config) turn it on."""
        return getattr(settings, self.size) > 0


@dataclass
class PhaseContext:
    """What a phase's sampling function is given: the partial tree, the env driver, the run's settings."""

    partial: Path
    pool: ChildPool
    config: Any
    """The run's ``SamplerConfig`` (a phase reads its own settings, and those of the phases it requires)."""
    start_depth: int
    """The depth at which the backward loop reached the start region."""
    backward_scale: Callable[[int], float]
    """The backward loop's arm action range at a depth (``backward.action_scale_at``)."""
    geometry: Optional[SocketGeometry]
    progress: bool = True
    name: str = ""
    stream: int = 0
    """The random stream of the phase running (``phases.stream_of``)."""

    def for_phase(self, name: str, stream: int) -> "PhaseContext":
        """This context for the phase ``name``, drawing from its own random stream."""
        return replace(self, name=name, stream=stream)

    @property
    def sampler(self) -> ChildSampler:
        """The env driver."""
        return self.pool.sampler

    def children_of(self, seeds: list, nodes: list, depth: int, count: int, scale: float,
                    shape: Optional[ActionShape] = None) -> dict:
        """``ChildPool.children_of`` in this phase's random stream."""
        return self.pool.children_of(seeds, nodes, depth, count, scale, self.stream, shape)

    def scale_for(self, travel: float) -> float:
        """The arm action range whose farthest child moves the end effector about ``travel`` metres."""
        c = self.config
        return float(np.clip(travel / self.sampler.translation_limit, c.min_action_scale, c.action_scale))

    def bar(self, total: int, initial: int, unit: str = "depth"):
        """A progress bar of this phase's steps."""
        return progress_bar(total=total, initial=initial, desc=f"{self.name} sampling", unit=unit,
                            enabled=self.progress)


def near_goal_last(reach: float, start_depth: int) -> int:
    """The last backward depth within the first ``reach`` of the loop's ``start_depth`` depths (at least 1)."""
    return max(1, math.ceil(reach * start_depth))


def near_goal_depths(reach: float, every: int, start_depth: int) -> list:
    """The backward depths whose seeds start near-goal lineages: every ``every``-th (from depth 1) up to
    ``near_goal_last``."""
    return list(range(1, near_goal_last(reach, start_depth) + 1, every))


def full_range_rotation(rotation: list, full: float) -> ActionShape:
    """An action shape with the ``rotation`` dims over the whole range ``full``, the others within the step's range."""

    def shape(actions: np.ndarray, scale: float) -> np.ndarray:
        actions[:, rotation] = actions[:, rotation] / scale * full
        return actions

    return shape


def grow_near_goal_lineages(ctx: PhaseContext, config: Any, group: str, counter: str, per_origin: int,
                            progress: Callable[[np.ndarray, np.ndarray], np.ndarray],
                            least: Callable[[float], float], shape: Optional[ActionShape] = None,
                            range_scale: float = 1.0) -> None:
    """Grow ``per_origin`` lineages from each backward seed of ``near_goal_depths`` for ``config.depth`` steps
    (``config``: a near-goal phase's settings, with ``depth``, ``reach``, ``every`` and ``children``).

    At each step every live lineage gets ``config.children`` children within ``range_scale`` of the backward loop's
    range at its origin (reshaped by ``shape``), all labelled the origin's depth plus the step, and keeps the one that
    went farthest by ``progress(ee [n, 7], lineage [n])`` (how far each child went its lineage's way from the
    lineage's origin); a lineage whose best child gained less than ``least(range)`` on its last step ends there. Steps
    go to ``seeds/<group>_<k>`` with the live lineages, their labels and progress for a resume; ``counter`` counts
    them.
    """
    depths = near_goal_depths(config.reach, config.every, ctx.start_depth)
    with h5py.File(ctx.partial, "r") as f:
        done = int(f.attrs.get(counter, 0))
        if done >= config.depth:
            return
        if done == 0:
            firsts = [tree_file.read_seeds(f[f"seeds/depth_{d}"]) for d in depths]
            seeds, nodes = [s[0] for s, _ in firsts], [n[0] for _, n in firsts]
            seeds, nodes = [s for s in seeds for _ in range(per_origin)], list(np.repeat(nodes, per_origin))
            labels, live, gone = np.repeat(depths, per_origin), np.arange(len(seeds)), np.zeros(len(seeds))
        else:
            last = f[f"seeds/{group}_{done}"]
            seeds, nodes = tree_file.read_seeds(last)
            labels, live, gone = (np.asarray(last.attrs[k]) for k in ("label", "lineage", "progress"))
    bar = ctx.bar(config.depth, done, unit="step")
    for k in range(done, config.depth):
        if not len(live):
            break
        merged, floor = {}, np.zeros(len(live))
        # One range per origin depth: the backward loop's there, so a lineage moves as the loop's children did.
        for label in np.unique(labels):
            rows = np.flatnonzero(labels == label)
            scale = ctx.backward_scale(int(label)) * range_scale
            part = ctx.children_of([seeds[i] for i in rows], [nodes[i] for i in rows], k * 1000 + int(label),
                                   config.children, scale, shape=shape)
            part["lineage"] = np.repeat(rows, config.children)
            merged = part if not merged else {key: np.concatenate([merged[key], part[key]]) for key in merged}
            floor[rows] = least(scale)
        order = np.argsort(merged.pop("lineage"), kind="stable")  # back to lineage order
        merged = {key: value[order] for key, value in merged.items()}
        along = progress(merged["ee"].astype(np.float64), np.repeat(live, config.children))
        chosen = np.arange(len(live)) * config.children + along.reshape(len(live), -1).argmax(1)
        best, labels = along[chosen], labels + 1
        goes_on = best - gone >= floor
        nodes = tree_file.append_depth(
            ctx.partial, merged, np.repeat(labels, config.children), chosen[goes_on], group=f"{group}_{k + 1}",
            counter=counter, count=k + 1,
            attrs={"label": labels[goes_on], "lineage": live[goes_on], "progress": best[goes_on]})
        seeds = tree_file.seeds_at(merged, chosen[goes_on])
        labels, live, gone = labels[goes_on], live[goes_on], best[goes_on]
        bar.update(1)
    bar.close()


def origin_poses(ctx: PhaseContext, reach: float, every: int) -> np.ndarray:
    """The end-effector poses ``[origins, 7]`` at the backward seeds of ``near_goal_depths``."""
    with h5py.File(ctx.partial, "r") as f:
        nodes = [int(f[f"seeds/depth_{d}/node"][0]) for d in near_goal_depths(reach, every, ctx.start_depth)]
        return f["tcp_pose"][()][nodes].astype(np.float64)


def directions_at(count: int, elevation_deg) -> np.ndarray:
    """Unit vectors ``[count, 3]``: azimuths spread evenly, each at its elevation (degrees; one, or cycled over)."""
    azimuth = 2 * np.pi * np.arange(count) / count
    elevation = np.deg2rad(np.atleast_1d(np.asarray(elevation_deg, float)))[np.arange(count) % np.size(elevation_deg)]
    return np.stack([np.cos(azimuth) * np.cos(elevation), np.sin(azimuth) * np.cos(elevation), np.sin(elevation)], -1)


def farthest_along(ee: np.ndarray, origin: np.ndarray, directions: np.ndarray,
                   penalty: Optional[np.ndarray] = None) -> np.ndarray:
    """Row of each lineage's child that went farthest from ``origin`` along the lineage's direction, less ``penalty``.

    ``ee`` ``[lineages * children, >= 3]`` holds the children lineage by lineage (``ChildPool.children_of``'s order):
    their end-effector poses, or rotation vectors with ``directions`` the lineages' axes.
    """
    along = np.einsum("lcx,lx->lc", (ee[:, :3] - origin).reshape(len(directions), -1, 3), directions)
    if penalty is not None:
        along = along - penalty.reshape(along.shape)
    return np.arange(len(directions)) * along.shape[1] + along.argmax(1)


def caught_penalty(tip: np.ndarray, geometry: SocketGeometry, side: bool) -> np.ndarray:
    """Metres off each lineage child's score: 1 plus 100 times how far in it is for a child caught in the opening.

    Face lineages: caught below ``face_seed_height`` (in the opening's mouth); side and turn lineages: in the opening.
    Never chosen while a child of its lineage is free, and a lineage whose children are all caught keeps the least
    deep, so it climbs out instead of staying in the mouth, labelled as the face.
    """
    if side:
        caught, depth = geometry.in_opening(tip), -tip[:, 2]
    else:
        caught, depth = tip[:, 2] < geometry.face_seed_height, geometry.face_seed_height - tip[:, 2]
    return np.where(caught, 1.0 + 100.0 * depth, 0.0)  # a millimetre deeper outweighs any lineage step


def out_of_opening(merged: dict, chosen: np.ndarray, geometry: SocketGeometry) -> tuple:
    """``merged`` without the children in the opening other than ``chosen``; the chosen rows' new indices; how many
    were dropped.

    A lineage's or push child that went into the opening is labelled by where it started (the face or the side),
    while it may be a step from the goal: kept, it would teach the reward that the inside of the opening is far.
    """
    keep = ~geometry.in_opening(merged["tip_in_socket"])
    keep[chosen] = True
    return {k: v[keep] for k, v in merged.items()}, np.cumsum(keep)[chosen] - 1, int((~keep).sum())


def rotation_from(q: np.ndarray, q0: np.ndarray) -> np.ndarray:
    """Radians between quaternions ``q [n, 4]`` and ``q0 [4]``."""
    return 2 * np.arccos(np.clip(np.abs(q @ q0), 0.0, 1.0))


def rotation_vectors(q: np.ndarray, q0: np.ndarray) -> np.ndarray:
    """Rotation vectors ``[n, 3]`` (world frame, rad) turning quaternions ``q0 [n, 4]`` into ``q [n, 4]`` (wxyz)."""
    rel = quaternion_multiply(torch.as_tensor(q), quaternion_invert(torch.as_tensor(q0)))  # the short way round
    return quaternion_to_axis_angle(rel).numpy()
