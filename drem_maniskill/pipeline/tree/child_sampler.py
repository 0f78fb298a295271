"""The env driver of backward sampling: restore a seed state, apply random actions, record the children.

``ChildSampler`` is one env (any ManiSkill env, read through ``envs.adapter``); ``ChildPool`` adds worker processes,
each with its own env, and the run's random streams, so every phase draws its children the same way.
"""

from __future__ import annotations

from typing import Callable, Optional

import gymnasium as gym
import numpy as np
import torch

from drem_maniskill.envs import check_env_id
from drem_maniskill.envs.adapter import adapter_for
from drem_maniskill.utils.state import broadcast_state, first_leaf, state_at


def _batch_rows(values: np.ndarray, start: int, n: int) -> np.ndarray:
    """Rows ``start`` to ``start + n`` of ``values``, the last one repeated to fill a batch of ``n`` envs."""
    rows = np.asarray(values[start : start + n])
    return np.concatenate([rows, np.repeat(rows[-1:], n - len(rows), 0)])


class ChildSampler:
    """An env that restores a seed state and applies random actions, in batches of ``num_envs``."""

    def __init__(self, env_id: str, env_kwargs: dict, episode_seed: Optional[int], expert_first_ee=None,
                 start_radius: float = 0.03, images: bool = True):
        # Without images no step renders (on the CPU, rendering is most of a step: 0.31 s against 0.012 s measured
        # on PlugCharger-v1's two cameras).
        self.images = images
        kwargs = {**env_kwargs, "obs_mode": "rgb" if images else "state_dict", "render_mode": None}
        self.env = gym.make(check_env_id(env_id), **kwargs)
        self.unwrapped = self.env.unwrapped
        self.adapter = adapter_for(self.env)
        # Colours and object poses of the expert's episode come with its seed.
        self.env.reset(seed=episode_seed)
        self.n = self.unwrapped.num_envs
        # End-effector poses are compared with the expert's as if the socket were where the expert had it.
        placements = self.adapter.placements()
        self.reference_placement = None if placements is None else placements[0].clone()
        self.action_dim = int(self.env.action_space.shape[-1])
        self.expert_first_ee = expert_first_ee
        self.start_radius = start_radius
        # Gripper actions are absolute targets: a scaled-down range would close the gripper, so
        # they are always drawn from the full range.
        mapping = getattr(self.unwrapped.agent.controller, "action_mapping", {}) or {}
        self.full_range_dims = [i for name, (a, b) in mapping.items() if "gripper" in name for i in range(a, b)]

    def random_actions(self, rng: np.random.Generator, count: int, scale: float) -> np.ndarray:
        """``count`` uniform random actions: arm dims in [-scale, scale], gripper dims in [-1, 1]."""
        actions = rng.uniform(-scale, scale, size=(count, self.action_dim))
        if self.full_range_dims and scale != 1.0:
            actions[:, self.full_range_dims] = rng.uniform(-1.0, 1.0, size=(count, len(self.full_range_dims)))
        return actions

    def in_start_region(self) -> torch.Tensor:
        """Start-region flags ``[num_envs]`` of the current states."""
        return self.adapter.in_start_region(self.expert_first_ee, self.start_radius)

    @property
    def vertical_dim(self) -> int:
        """The action dim that moves the end effector up and down (an ``ee_delta_pos``/``pose`` arm controller's z)."""
        controller = self.unwrapped.agent.controller
        arm = getattr(controller, "controllers", {}).get("arm")
        name = type(arm).__name__ if arm is not None else ""
        if "EEPos" not in name and "EEPose" not in name:
            raise ValueError("pushing down needs an end-effector delta arm controller (pd_ee_delta_pose), not "
                             f"{name or controller}")
        return int((getattr(controller, "action_mapping", {}) or {}).get("arm", (0, 0))[0]) + 2

    @property
    def rotation_dims(self) -> list:
        """The action dims that turn the end effector (a ``pd_ee_delta_pose`` arm controller's rotation)."""
        controller = self.unwrapped.agent.controller
        arm = getattr(controller, "controllers", {}).get("arm")
        if "EEPose" not in (type(arm).__name__ if arm is not None else ""):
            raise ValueError("turning needs an end-effector delta pose arm controller (pd_ee_delta_pose), not "
                             f"{arm or controller}")
        first = int((getattr(controller, "action_mapping", {}) or {}).get("arm", (0, 0))[0])
        return [first + 3, first + 4, first + 5]

    @property
    def translation_limit(self) -> float:
        """Metres of end-effector travel a full-scale arm action asks for (the controller's ``pos_upper``)."""
        arm = getattr(self.unwrapped.agent.controller, "controllers", {}).get("arm")
        limit = getattr(getattr(arm, "config", None), "pos_upper", None)
        return float(np.max(limit)) if limit is not None else 1.0

    @property
    def rotation_limit(self) -> float:
        """Radians a full-scale rotation action turns the end effector (a ``pd_ee_delta_pose`` arm's ``rot_lower``)."""
        arm = getattr(self.unwrapped.agent.controller, "controllers", {}).get("arm")
        limit = getattr(getattr(arm, "config", None), "rot_lower", None)
        if limit is None:
            raise ValueError("turning needs an end-effector delta pose arm controller (pd_ee_delta_pose), not "
                             f"{arm or self.unwrapped.agent.controller}")
        return float(np.max(np.abs(limit)))

    def random_colors(self, rng: np.random.Generator, count: int) -> Optional[np.ndarray]:
        """``count`` part and socket colours ``[count, 6]`` drawn as the task's resets draw them (None: no colours)."""
        if not self.adapter.colorable:
            return None
        return rng.uniform(*self.unwrapped.color_range, size=(count, 6))

    def random_placements(self, rng: np.random.Generator, count: int) -> Optional[np.ndarray]:
        """``count`` socket placements ``[count, 3]`` drawn as the task's resets draw them (None: no socket)."""
        if not self.adapter.placeable:
            return None
        return self.unwrapped.random_socket_placements(rng, count)

    def children(self, seed_state: dict, actions: np.ndarray, colors: Optional[np.ndarray] = None,
                 placements: Optional[np.ndarray] = None) -> dict:
        """Apply each action from ``seed_state`` (each child in its row of ``colors`` and ``placements``): the
        children's observations, start flags and states.

        ``tcp_pose`` and ``ee`` are given at the expert's socket placement, so that they compare
        with the expert's whatever placement a child was moved to.
        """
        out = {k: [] for k in ("fixed_rgb", "wrist_rgb", "ft", "tcp_pose", "ee", "in_start_region", "state", "colors",
                               "placement", "tip_in_socket", "poses")}
        for start in range(0, len(actions), self.n):
            chunk = torch.as_tensor(actions[start : start + self.n], dtype=torch.float32)
            k = len(chunk)
            if k < self.n:
                chunk = torch.cat([chunk, chunk.new_zeros(self.n - k, chunk.shape[1])])
            self.adapter.set_state(broadcast_state(seed_state, self.n))
            if colors is not None:
                # Colours are not state: the restored step replays the same whatever they are.
                self.adapter.set_colors(_batch_rows(colors, start, self.n))
            if placements is not None:
                self.adapter.place(_batch_rows(placements, start, self.n))
            obs, *_ = self.env.step(chunk)
            placed = self.adapter.placements()
            if placed is not None:
                out["placement"].append(placed[:k].cpu().numpy())
            rendered = self.adapter.colors()  # what the images show, drawn here or not
            if rendered is not None:
                out["colors"].append(rendered[:k].numpy())
            tip = self.adapter.tip_in_socket()
            if tip is not None:
                out["tip_in_socket"].append(tip[:k].cpu().numpy())
            for m, image in (self.adapter.images(obs) if self.images else {}).items():
                out[f"{m}_rgb"].append(image[:k].cpu().numpy())
            ft = self.adapter.ft()
            out["ft"].append(ft[:k].cpu().numpy() if ft is not None else np.zeros((k, 8, 6), np.float32))
            ee = self.adapter.ee_state_at(self.reference_placement)[:k].cpu().numpy()
            out["tcp_pose"].append(ee[:, :7])
            out["ee"].append(ee)
            out["in_start_region"].append(self.in_start_region()[:k].cpu().numpy())
            out["state"].append(self.adapter.flatten(self.adapter.get_state())[:k].cpu().numpy())
            out["poses"].append(self.adapter.poses()[:k].cpu().numpy())
        return {k: np.concatenate(v) for k, v in out.items() if v}

    def expert_ee_states(self, states: dict) -> np.ndarray:
        """End-effector states ``[T + 1, 8]`` of the expert, by restoring each recorded env state."""
        length = len(first_leaf(states))
        out = []
        for t in range(length):
            self.adapter.set_state(broadcast_state(state_at(states, t), self.n))
            out.append(self.adapter.ee_state_at(self.reference_placement)[0].cpu().numpy())
        return np.stack(out)

    def close(self):
        """Close the env."""
        self.env.close()


_WORKER: Optional[ChildSampler] = None


def _worker_init(env_id, env_kwargs, episode_seed, expert_first_ee, start_radius, images=True):
    global _WORKER
    torch.set_num_threads(1)
    _WORKER = ChildSampler(env_id, env_kwargs, episode_seed, expert_first_ee, start_radius, images)


def _worker_children(args):
    flat_state, actions, colors, placements = args
    return _WORKER.children(_WORKER.adapter.unflatten(flat_state), actions, colors, placements)


def random_streams(seed: int, depth: int, stream: int = 0) -> tuple:
    """The action, colour and placement generators of one depth of one random stream.

    Functions of the depth, so a resumed run draws the same actions. Colours and placements have streams of their
    own, so turning them off leaves the actions as they were. Stream 0 is the backward loop's; its colour and
    placement generators take the entropy words 1 and 2, so the other streams start at 3 (``phases.stream_of``).
    """
    actions = np.random.default_rng([seed, depth] + ([stream] if stream else []))
    colors = np.random.default_rng([seed, depth, 1 + 3 * stream])
    return actions, colors, np.random.default_rng([seed, depth, 2 + 3 * stream])


ActionShape = Callable[[np.ndarray, float], np.ndarray]
"""Reshapes a seed's random actions ``[count, action_dim]`` drawn within ``scale`` (in place or anew): a phase's push
or turn."""


class ChildPool:
    """A ``ChildSampler`` and, with ``workers > 1``, as many worker processes: the children of seeds, batched."""

    def __init__(self, sampler: ChildSampler, seed: int = 0, workers: int = 1, randomize_colors: bool = True,
                 randomize_placement: bool = True):
        self.sampler, self.seed, self.workers = sampler, seed, workers
        self.randomize_colors, self.randomize_placement = randomize_colors, randomize_placement
        self._pool = None

    def start_workers(self, env_id: str, env_kwargs: dict, episode_seed: Optional[int], expert_first_ee,
                      start_radius: float) -> None:
        """Start the worker processes (``workers > 1``), each making its own env as ``sampler`` was made."""
        if self.workers > 1 and self._pool is None:
            import multiprocessing as mp

            self._pool = mp.get_context("spawn").Pool(
                self.workers, initializer=_worker_init,
                initargs=(env_id, env_kwargs, episode_seed, expert_first_ee, start_radius, self.sampler.images))

    def children_of(self, seeds: list, seed_nodes: list, depth: int, count: int, scale: float, stream: int = 0,
                    shape: Optional[ActionShape] = None) -> dict:
        """``count`` children of every seed (arm actions within ``scale``, reshaped by ``shape``), each with fresh
        colours and placement where configured, merged in seed order; ``parent`` holds each child's seed node."""
        sampler = self.sampler
        rng, color_rng, place_rng = random_streams(self.seed, depth, stream)
        children = []
        for seed, node in zip(seeds, seed_nodes):
            actions = sampler.random_actions(rng, count, scale)
            if shape is not None:
                actions = shape(actions, scale)
            colors = sampler.random_colors(color_rng, count) if self.randomize_colors else None
            places = sampler.random_placements(place_rng, count) if self.randomize_placement else None
            if self._pool is None:
                res = sampler.children(sampler.adapter.unflatten(seed["state"]), actions, colors, places)
            else:
                parts = [p for p in np.array_split(np.arange(len(actions)), self.workers) if len(p)]
                outs = self._pool.map(_worker_children, [
                    (seed["state"], actions[p], None if colors is None else colors[p],
                     None if places is None else places[p]) for p in parts])
                res = {k: np.concatenate([o[k] for o in outs]) for k in outs[0]}
            res["parent"] = np.full(len(actions), node)
            children.append(res)
        return {k: np.concatenate([c[k] for c in children]) for k in children[0]}

    def close(self) -> None:
        """Close the env and stop the workers."""
        self.sampler.close()
        if self._pool is not None:
            self._pool.close()
            self._pool.join()
            self._pool = None
