"""Backward sampling into a task progress tree (Section III-A of the paper), then the extra phases turned on.

Starting from the goal state ``s_G`` (the expert trajectory's last state), at depth ``d`` every seed state gets ``M``
random actions, each applied from the restored seed state; the children are recorded with depth ``d + 1`` and their
parent. The next seeds are chosen by the progress measure: the paper's expert-guided measure (``N = 1``) keeps the
child whose end-effector pose is closest to the expert's pose ``d + 1`` steps before the goal, and ``N > 1`` keeps
the ``N`` closest. Sampling stops once at least ``N * delta`` seeds lie in the task's start region, or fails with a
clear error at ``max_depth``.

Any ManiSkill env works (``drem_maniskill.envs.adapter``): on our tasks the tree holds both cameras and the F/T
history; on a stock task its cameras and zeros for F/T. Where the robot has a gripper, the measure also compares the
gripper opening with the expert's, so the tree opens the gripper where the expert had it open.

The tree is written to ``<out>.partial`` step by step (``tree_file``) and renamed when complete; an interrupted run
resumes from the last complete step.
"""

from __future__ import annotations

import json
import math
from dataclasses import asdict
from functools import partial as bind
from pathlib import Path
from typing import Callable, Optional

import h5py
import numpy as np

from drem_maniskill.pipeline.tree import tree_file
from drem_maniskill.pipeline.tree.child_sampler import ChildPool, ChildSampler
from drem_maniskill.pipeline.tree.config import SamplerConfig
from drem_maniskill.pipeline.tree.expert import ExpertTrajectory, load_expert
from drem_maniskill.pipeline.tree.phases import PHASES, PhaseContext, stream_of
from drem_maniskill.utils.progress import progress_bar
from drem_maniskill.utils.state import broadcast_state, state_at


class NoStartRegionError(RuntimeError):
    """The tree reached ``max_depth`` before enough seeds were in the start region."""


def ee_distance(a: np.ndarray, b: np.ndarray, rotation_weight: float, gripper_weight: float = 0.0) -> np.ndarray:
    """Distance between end-effector states ``[.., 7]`` or ``[.., 8]`` (pose, gripper width): position L2 plus the
    weighted rotation angle, plus the weighted gripper-width difference when both carry one."""
    pos = np.linalg.norm(a[..., :3] - b[..., :3], axis=-1)
    dot = np.abs(np.sum(a[..., 3:7] * b[..., 3:7], axis=-1)).clip(0, 1)
    dist = pos + rotation_weight * 2 * np.arccos(dot)
    if gripper_weight and a.shape[-1] > 7 and b.shape[-1] > 7:
        dist = dist + gripper_weight * np.abs(a[..., 7] - b[..., 7])
    return dist


def median_step(expert_ee: np.ndarray, rotation_weight: float) -> float:
    """The demo's median end-effector step (``ee_distance``) among those that move; 0 for a demo that never moves."""
    step = ee_distance(expert_ee[:-1], expert_ee[1:], rotation_weight)
    moving = step[step > 1e-6]
    return float(np.median(moving)) if len(moving) else 0.0


def even_path(expert_ee: np.ndarray, rotation_weight: float, unit_scale: float = 1.0) -> np.ndarray:
    """The demo's end-effector path with every step split into equal parts of about its median step (times
    ``unit_scale``).

    Poses between two recorded ones are interpolated (position and gripper width linearly, the quaternion
    normalised-linearly). The recorded poses stay, the goal last; only the demo's own steps set the length.
    """
    step = ee_distance(expert_ee[:-1], expert_ee[1:], rotation_weight)
    unit = median_step(expert_ee, rotation_weight) * unit_scale
    if unit <= 0:
        return expert_ee
    rows = [expert_ee[:1]]
    for a, b, length in zip(expert_ee[:-1], expert_ee[1:], step):
        parts = max(int(np.rint(length / unit)), 1)
        f = (np.arange(1, parts + 1) / parts)[:, None]
        qb = b[3:7] * (1.0 if np.dot(a[3:7], b[3:7]) >= 0 else -1.0)  # the short way round
        q = (1 - f) * a[3:7] + f * qb
        mid = np.concatenate([(1 - f) * a[:3] + f * b[:3], q / np.linalg.norm(q, axis=1, keepdims=True),
                              (1 - f) * a[7:] + f * b[7:]], axis=1)
        mid[-1] = b  # the recorded pose itself, its quaternion's sign included
        rows.append(mid)
    return np.concatenate(rows).astype(expert_ee.dtype)


def graded_path(expert_ee: np.ndarray, rotation_weight: float, fraction: float, finest: float) -> np.ndarray:
    """The demo's path walked from the goal in steps of ``fraction`` of the path still left to the goal, between
    ``finest`` times the demo's median step and the median step; returned start first, the goal last.

    Near the goal the depths crowd (each moves the part a fixed share of the way that remains), so the reward's rise
    steepens as the part nears its goal; far from it the path is ``even_path``'s. The poses are those of
    ``even_path`` at ``finest`` times the median step, so every pose lies on the demo's path; its first pose stays.
    """
    unit = median_step(expert_ee, rotation_weight)
    if unit <= 0:
        return expert_ee
    fine = even_path(expert_ee, rotation_weight, unit_scale=finest)
    left = np.concatenate([np.cumsum(ee_distance(fine[:-1], fine[1:], rotation_weight)[::-1])[::-1], [0.0]])
    keep, at = [len(fine) - 1], 0.0
    for i in range(len(fine) - 2, -1, -1):  # away from the goal
        if left[i] - at >= np.clip(fraction * at, finest * unit, unit) - 1e-9 or i == 0:
            keep.append(i)
            at = left[i]
    return fine[keep[::-1]]


def action_scale_at(depth: int, expert_ee: np.ndarray, config: SamplerConfig, translation_limit: float) -> float:
    """The arm action range for the children of depth ``depth`` (``SamplerConfig.expert_step_scale``)."""
    if config.expert_step_scale <= 0:
        return config.action_scale
    goal = len(expert_ee) - 1
    if depth < goal:
        step = float(np.linalg.norm(expert_ee[goal - depth, :3] - expert_ee[goal - depth - 1, :3]))
    else:  # past the demo's first pose the target stays there: a chain still short of it goes on at the demo's pace
        steps = np.linalg.norm(np.diff(expert_ee[:, :3], axis=0), axis=1)
        step = float(np.median(steps[steps > 1e-6])) if (steps > 1e-6).any() else 0.0
    return float(np.clip(config.expert_step_scale * step / translation_limit, config.min_action_scale,
                         config.action_scale))


def backward_loop(partial: Path, pool: ChildPool, config: SamplerConfig, expert_ee: np.ndarray, depth: int,
                  seeds: list, seed_nodes: list, progress: bool = True,
                  demo_seed: Optional[Callable[[int], dict]] = None) -> int:
    """The paper's loop, from the seeds at ``depth`` until enough seeds are in the start region; returns that depth.

    With ``demo_seed`` (``SamplerConfig.seeds_from_demo``) the children at ``depth`` are drawn from
    ``demo_seed(depth)``, the demo's state, instead of from ``seeds``; ``seeds`` are still the chosen children, whose
    start-region flags end the loop (the tree's nodes, as in the paper) and which stay their children's recorded
    parents.
    """
    goal = len(expert_ee) - 1
    needed = math.ceil(config.num_seeds * config.delta)
    gripper_weight = config.gripper_weight if pool.sampler.adapter.gripper_idx else 0.0
    limit = config.depth_limit(goal)
    bar = progress_bar(total=limit, initial=depth, desc="backward sampling", unit="depth", enabled=progress)
    while (in_region := int(sum(bool(s["in_start_region"]) for s in seeds))) < needed:
        if depth >= limit:
            raise NoStartRegionError(
                f"backward sampling reached max_depth={limit} (demo of {goal} steps) with {in_region}/{len(seeds)} "
                f"seeds in the start region (needed {needed}); raise --max-depth or --action-scale, or check the "
                f"expert")
        scale = action_scale_at(depth, expert_ee, config, pool.sampler.translation_limit)
        parents = seeds if demo_seed is None else [demo_seed(depth)]
        merged = pool.children_of(parents, seed_nodes, depth, config.num_children, scale)
        bar.set_postfix(children=config.num_children * len(seeds), in_start=in_region)
        # Expert-guided progress measure: the closest end-effector states to the expert's d + 1 steps back.
        dist = ee_distance(merged["ee"], expert_ee[max(goal - (depth + 1), 0)], config.rotation_weight, gripper_weight)
        chosen = np.argsort(dist, kind="stable")[: config.num_seeds]
        depth += 1
        seed_nodes = tree_file.append_depth(partial, merged, depth, chosen)
        seeds = tree_file.seeds_at(merged, chosen)
        bar.update(1)
    bar.close()
    return depth


def backward_sample(expert_path: str, out_path: str, config: Optional[SamplerConfig] = None,
                    progress: bool = True) -> str:
    """Build the task progress tree from an expert trajectory (the paper's loop, then the phases turned on); returns
    the tree's path."""
    config = config or SamplerConfig()
    out_path = Path(out_path)
    out_path.parent.mkdir(parents=True, exist_ok=True)
    partial = tree_file.partial_path(out_path)
    expert = load_expert(expert_path, config.episode)
    sampler = ChildSampler(expert.env_id, expert.env_kwargs, expert.episode_seed, start_radius=config.start_radius,
                           images=config.images)
    pool = ChildPool(sampler, config.seed, config.workers, config.randomize_colors, config.randomize_placement)
    try:
        _check(expert_path, expert, sampler, config)
        # The measure compares with the expert's end-effector states, read from its env states (not its
        # observations), so any demo with env_states works.
        expert_ee = sampler.expert_ee_states(expert.states)
        if config.even_path and config.graded_path > 0:
            expert_ee = graded_path(expert_ee, config.rotation_weight, config.graded_path, config.graded_finest)
        elif config.even_path:
            expert_ee = even_path(expert_ee, config.rotation_weight)
        sampler.expert_first_ee = expert_ee[0]
        pool.start_workers(expert.env_id, expert.env_kwargs, expert.episode_seed, expert_ee[0], config.start_radius)
        depth, seeds, nodes = _open_or_resume(partial, expert, expert_ee, config, sampler)
        demo_seed = bind(_demo_seed, expert, sampler) if config.seeds_from_demo else None
        if tree_file.start_depth(partial) is None:
            depth = backward_loop(partial, pool, config, expert_ee, depth, seeds, nodes, progress, demo_seed)
        context = PhaseContext(
            partial, pool, config, tree_file.mark_start_depth(partial, depth),
            bind(action_scale_at, expert_ee=expert_ee, config=config, translation_limit=sampler.translation_limit),
            socket_geometry(sampler, config), progress)
        for name, settings in config.phases_on().items():
            PHASES[name].sample(context.for_phase(name, stream_of(name)), settings)
        return tree_file.finish(partial, out_path)
    finally:
        pool.close()


def socket_geometry(sampler: ChildSampler, config: SamplerConfig):
    """The task's socket geometry where a phase that is on needs it, else None: the paper's loop never reads it."""
    if not any(PHASES[name].needs_geometry for name in config.phases_on()):
        return None
    return sampler.adapter.socket_geometry()


def _check(expert_path: str, expert: ExpertTrajectory, sampler: ChildSampler, config: SamplerConfig) -> None:
    """Refuse, before sampling anything, an expert whose cameras differ or phases that cannot run on this env."""
    missing = [m for m, uid in sampler.adapter.camera_map.items() if expert.camera_map.get(m) != uid]
    if missing:
        raise ValueError(
            f"{expert_path} recorded cameras {expert.camera_map}, but {expert.env_id} samples "
            f"{sampler.adapter.camera_map}; record the expert with the same env and sensor configs")
    on = config.phases_on()
    for name, phase in ((n, PHASES[n]) for n in on):
        for required in phase.requires:
            if required not in on:
                raise ValueError(f"the {name} phase starts from the {required} phase's seeds: turn that on too "
                                 f"({PHASES[required].switch()})")
        if phase.needs_geometry and sampler.adapter.socket_geometry() is None:
            raise ValueError(f"the {name} phase needs one of our insertion tasks, which know where the socket's "
                             f"opening is; {expert.env_id} does not: sample it with the phase off ({phase.switch()})")


def resumable(saved: dict, now: dict) -> bool:
    """Whether a partial tree with header ``saved`` goes on under header ``now``: the same env and expert, and a
    config that ``SamplerConfig.can_resume`` it (a config ``SamplerConfig.from_dict`` cannot read: no)."""
    try:
        old = SamplerConfig.from_dict(saved.get("config", {}))
    except (ValueError, TypeError):
        return False
    rest = [{k: v for k, v in h.items() if k not in ("config", "socket_geometry")} for h in (saved, now)]
    return SamplerConfig.from_dict(now["config"]).can_resume(old) and rest[0] == rest[1]


def _open_or_resume(partial: Path, expert: ExpertTrajectory, expert_ee: np.ndarray, config: SamplerConfig,
                    sampler: ChildSampler) -> tuple:
    """The depth, seeds and seed nodes to go on from: a resumable partial file's last complete depth, else a new file
    holding the goal state (depth 0)."""
    geometry = socket_geometry(sampler, config)
    header = dict(config=config.to_dict(), env_id=expert.env_id, env_kwargs=expert.env_kwargs,
                  episode_seed=expert.episode_seed, expert_length=expert.length - 1,
                  camera_map=sampler.adapter.camera_map, has_ft=sampler.adapter.has_ft, action_dim=sampler.action_dim,
                  socket_geometry=None if geometry is None else asdict(geometry))
    header = json.loads(json.dumps(header))  # as it reads back
    if partial.exists():
        resumed = None
        try:
            with h5py.File(partial, "r") as f:
                if resumable(tree_file.read_header(f), header):
                    depth = int(f.attrs["completed_depth"])
                    resumed = (depth, *tree_file.read_seeds(f[f"seeds/depth_{depth}"]))
        except (OSError, KeyError):
            pass  # unreadable: start over
        if resumed is not None:
            # After closing: HDF5 will not open a file for writing that this process holds open for reading.
            tree_file.truncate(partial)
            tree_file.set_header(partial, header)
            return resumed
        partial.unlink()  # from another config: start over
    anchors = {}
    for which, t in (("first", 0), ("last", expert.length - 1)):  # the scene's poses beside the recorded images
        sampler.adapter.set_state(broadcast_state(state_at(expert.states, t), sampler.n))
        anchors[which] = {**getattr(expert, f"{which}_obs"), "poses": sampler.adapter.poses()[0].cpu().numpy()}
    root, flat, in_region = _goal_node(expert, expert_ee, sampler)
    tree_file.create(partial, header, anchors["first"], anchors["last"], expert_ee, root)
    return 0, [dict(state=flat[0], in_start_region=in_region)], [0]


def _demo_seed(expert: ExpertTrajectory, sampler: ChildSampler, depth: int) -> dict:
    """The state the children at ``depth`` start from under ``seeds_from_demo``: the demo's ``depth`` steps before
    its goal (its first state beyond), flat; the sampler's env is left in it."""
    t = max(expert.length - 1 - depth, 0)
    sampler.adapter.set_state(broadcast_state(state_at(expert.states, t), sampler.n))
    return dict(state=sampler.adapter.flatten(sampler.adapter.get_state())[0].cpu().numpy())


def _goal_node(expert: ExpertTrajectory, expert_ee: np.ndarray, sampler: ChildSampler) -> tuple:
    """The root node's rows (the goal state, as the expert's last step recorded it), its flat state and start flag."""
    flat = _demo_seed(expert, sampler, 0)["state"][None]
    in_region = bool(sampler.in_start_region()[0])
    root = {f"{m}_rgb": expert.last_obs[f"{m}_rgb"][None] for m in expert.camera_map if sampler.images}
    extras = dict(colors=sampler.adapter.colors(), placement=sampler.adapter.placements(),
                  tip_in_socket=sampler.adapter.tip_in_socket())  # colours: the expert episode's, from its seed
    root.update({k: v[:1].cpu().numpy() for k, v in extras.items() if v is not None})
    root.update(ft=expert.last_obs.get("ft", np.zeros((8, 6), np.float32))[None], tcp_pose=expert_ee[-1:, :7],
                poses=sampler.adapter.poses()[:1].cpu().numpy(),
                in_start_region=np.array([in_region]), state=flat, parent=np.array([-1]))
    return root, flat, in_region
