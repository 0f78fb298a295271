"""What an extra phase of backward sampling is (``Phase``), what it is given (``PhaseContext``), and the lineage
helpers the phases share."""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, Callable, Optional

import numpy as np
import torch
from mani_skill.utils.geometry.rotation_conversions import (
    quaternion_invert,
    quaternion_multiply,
    quaternion_to_axis_angle,
)

from drem_maniskill.envs.adapter import SocketGeometry
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
