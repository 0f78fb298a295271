"""Backward sampling into a task progress tree (Section III-A of the paper).

Starting from the goal state ``s_G`` (the expert trajectory's last state), at depth ``d`` every
seed state gets ``M`` random actions, each applied from the restored seed state; the children
are recorded with depth ``d + 1`` and their parent. The next seeds are chosen by the progress
measure; the paper's expert-guided measure (``N = 1``) keeps the child whose end-effector pose
is closest to the expert's pose ``d + 1`` steps before the goal, and ``N > 1`` keeps the ``N``
closest. Sampling stops once at least ``N * delta`` seeds lie in the task's start region, or
fails with a clear error at ``max_depth``.

The expert trajectory is read in ManiSkill's format (``RecordEpisode``'s .h5 + .json): only
its observations (end-effector poses, and the first and last observations for the reward's
normalisation) and its environment states (the goal state) are used, never its actions.

Output: one HDF5 file (see ``DATASET_KEYS``) written to ``<out>.partial`` depth by depth and
renamed when complete; an interrupted run resumes from the last complete depth.
"""

from __future__ import annotations

import json
import math
import os
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Optional

import h5py
import numpy as np
import torch
from tqdm import tqdm

DATASET_KEYS = ("fixed_rgb", "wrist_rgb", "ft", "tcp_pose", "depth", "parent", "in_start_region", "is_seed")


@dataclass
class SamplerConfig:
    """Backward-sampling hyper-parameters; defaults are the paper's (M = 500, N = 1)."""

    num_children: int = 500
    """M: random actions applied to each seed state."""
    num_seeds: int = 1
    """N: seeds kept per depth (the paper's expert-guided measure uses 1)."""
    delta: float = 0.5
    """Stop when at least ceil(N * delta) seeds are in the start region."""
    max_depth: int = 80
    action_scale: float = 1.0
    """Random actions are uniform in [-action_scale, action_scale] (normalised action space)."""
    rotation_weight: float = 0.05
    """Metres per radian when comparing end-effector poses with the expert's."""
    seed: int = 0
    episode: int = 0
    """Which episode of the expert file to use."""
    workers: int = 1
    """Worker processes, each with its own env (children of one seed are split among them)."""

    @classmethod
    def preset(cls, name: str, **overrides) -> "SamplerConfig":
        """``paper`` (M = 500) or ``quick`` (M = 24, for minutes-long runs)."""
        presets = {"paper": {}, "quick": dict(num_children=24), "tiny": dict(num_children=4, max_depth=40)}
        if name not in presets:
            raise ValueError(f"unknown sampler preset {name!r}; choose one of {list(presets)}")
        return cls(**{**presets[name], **overrides})


class NoStartRegionError(RuntimeError):
    """The tree reached ``max_depth`` before enough seeds were in the start region."""


# ---------------------------------------------------------------------------- expert input
@dataclass
class ExpertTrajectory:
    """The parts of a recorded expert episode that DREM uses (no actions)."""

    env_id: str
    env_kwargs: dict
    episode_seed: Optional[int]
    goal_state: np.ndarray  # flat env state of the last step
    tcp_poses: np.ndarray  # [T + 1, 7]
    first_obs: dict  # fixed_rgb, wrist_rgb, ft of step 0
    last_obs: dict  # of step T
    states: dict = field(default_factory=dict)


def _read_tree(group) -> dict:
    out = {}
    for key, value in group.items():
        out[key] = _read_tree(value) if isinstance(value, h5py.Group) else value[()]
    return out


def load_expert(h5_path: str, episode: int = 0) -> ExpertTrajectory:
    """Read one episode of a ManiSkill trajectory file (``.h5`` with its ``.json`` beside it)."""
    h5_path = Path(h5_path)
    json_path = h5_path.with_suffix(".json")
    if not h5_path.exists():
        raise FileNotFoundError(f"expert trajectory {h5_path} not found; record one with `drem-maniskill record-expert`")
    if not json_path.exists():
        raise FileNotFoundError(f"{json_path} (the metadata RecordEpisode writes beside {h5_path.name}) not found")
    meta = json.loads(json_path.read_text())
    episodes = meta.get("episodes", [])
    if episode >= len(episodes):
        raise ValueError(f"{h5_path} has {len(episodes)} episodes; episode {episode} does not exist")
    ep = episodes[episode]
    try:
        with h5py.File(h5_path, "r") as f:
            traj = f[f"traj_{ep.get('episode_id', episode)}"]
            if "env_states" not in traj:
                raise ValueError(f"{h5_path} has no env_states; record with RecordEpisode(record_env_state=True)")
            obs = traj["obs"]
            missing = [k for k in ("sensor_data/fixed_camera/rgb", "sensor_data/wrist_camera/rgb", "extra/tcp_pose") if k not in obs]
            if missing:
                raise ValueError(
                    f"{h5_path} lacks observations {missing}: record the expert with obs_mode='rgb' "
                    "(drem-maniskill record-expert does)"
                )
            states = _read_tree(traj["env_states"])
            cams = {c: obs[f"sensor_data/{c}_camera/rgb"] for c in ("fixed", "wrist")}
            ft = obs["extra/ft"][()] if "extra/ft" in obs else None
            tcp = obs["extra/tcp_pose"][()]

            def pick(i):
                out = {f"{c}_rgb": cams[c][i] for c in cams}
                if ft is not None:
                    out["ft"] = ft[i]
                return out

            first, last = pick(0), pick(-1)
    except OSError as err:
        raise ValueError(f"cannot read {h5_path}: {err}. Is it a complete HDF5 file? Re-record it.") from err
    kwargs = dict(meta["env_info"].get("env_kwargs", {}))
    return ExpertTrajectory(
        env_id=meta["env_info"]["env_id"], env_kwargs=kwargs, episode_seed=ep.get("episode_seed"),
        goal_state=None, tcp_poses=tcp, first_obs=first, last_obs=last, states=states,
    )


def _state_at(states: dict, index: int) -> dict:
    return {k: (_state_at(v, index) if isinstance(v, dict) else torch.as_tensor(v[index : index + 1])) for k, v in states.items()}


# ---------------------------------------------------------------------------- children
class ChildSampler:
    """An env that restores a seed state and applies random actions, in batches of ``num_envs``."""

    def __init__(self, env_id: str, env_kwargs: dict, episode_seed: Optional[int]):
        import gymnasium as gym

        import drem_maniskill  # noqa: F401

        kwargs = {**env_kwargs, "obs_mode": "rgb", "render_mode": None}
        self.env = gym.make(env_id, **kwargs)
        self.unwrapped = self.env.unwrapped
        # Colours and socket pose of the expert's episode come with its seed.
        self.env.reset(seed=episode_seed)
        self.n = self.unwrapped.num_envs

    def children(self, seed_state: dict, actions: np.ndarray) -> dict:
        """Apply each action from ``seed_state``; returns observations, start flags and states."""
        out = {k: [] for k in ("fixed_rgb", "wrist_rgb", "ft", "tcp_pose", "in_start_region", "state")}
        batched = {k: v for k, v in seed_state.items()}
        for start in range(0, len(actions), self.n):
            chunk = torch.as_tensor(actions[start : start + self.n], dtype=torch.float32)
            k = len(chunk)
            if k < self.n:
                chunk = torch.cat([chunk, chunk.new_zeros(self.n - k, chunk.shape[1])])
            self.unwrapped.set_state_dict(_broadcast(batched, self.n))
            obs, *_ = self.env.step(chunk)
            out["fixed_rgb"].append(obs["sensor_data"]["fixed_camera"]["rgb"][:k].cpu().numpy())
            out["wrist_rgb"].append(obs["sensor_data"]["wrist_camera"]["rgb"][:k].cpu().numpy())
            out["ft"].append(obs["extra"]["ft"][:k].cpu().numpy())
            out["tcp_pose"].append(obs["extra"]["tcp_pose"][:k].cpu().numpy())
            out["in_start_region"].append(self.unwrapped.in_start_region()[:k].cpu().numpy())
            out["state"].append(self.unwrapped.get_state()[:k].cpu().numpy())
        return {k: np.concatenate(v) for k, v in out.items()}

    def close(self):
        """Close the env."""
        self.env.close()


def _broadcast(state: dict, n: int) -> dict:
    return {k: (_broadcast(v, n) if isinstance(v, dict) else torch.as_tensor(v).expand(n, *torch.as_tensor(v).shape[1:]).clone())
            for k, v in state.items()}


_WORKER: Optional[ChildSampler] = None


def _worker_init(env_id, env_kwargs, episode_seed):
    global _WORKER
    torch.set_num_threads(1)
    _WORKER = ChildSampler(env_id, env_kwargs, episode_seed)


def _worker_children(args):
    flat_state, actions = args
    return _WORKER.children(_WORKER_state(flat_state), actions)


def _WORKER_state(flat):
    template = _WORKER.unwrapped.get_state_dict()
    from drem_maniskill.envs.insertion_base import _unflatten_like

    return _unflatten_like(template, torch.as_tensor(flat)[None])


def pose_distance(a: np.ndarray, b: np.ndarray, rotation_weight: float) -> np.ndarray:
    """Distance between raw poses ``[.., 7]``: position L2 plus weighted rotation angle."""
    pos = np.linalg.norm(a[..., :3] - b[..., :3], axis=-1)
    dot = np.abs(np.sum(a[..., 3:] * b[..., 3:], axis=-1)).clip(0, 1)
    return pos + rotation_weight * 2 * np.arccos(dot)


# ---------------------------------------------------------------------------- the tree
def backward_sample(expert_path: str, out_path: str, config: SamplerConfig = SamplerConfig(), progress: bool = True) -> str:
    """Build the task progress tree from an expert trajectory; returns the dataset's path."""
    out_path = Path(out_path)
    partial = out_path.with_name(out_path.name + ".partial")
    expert = load_expert(expert_path, config.episode)
    goal_index = len(expert.tcp_poses) - 1
    rng = np.random.default_rng(config.seed)

    sampler = ChildSampler(expert.env_id, expert.env_kwargs, expert.episode_seed)
    pool = None
    if config.workers > 1:
        import multiprocessing as mp

        pool = mp.get_context("spawn").Pool(
            config.workers, initializer=_worker_init, initargs=(expert.env_id, expert.env_kwargs, expert.episode_seed)
        )
    try:
        depth, seeds, seed_nodes = _open_or_resume(partial, expert, config, sampler, goal_index)
        needed = math.ceil(config.num_seeds * config.delta)
        # The random stream is a function of the depth, so a resumed run draws the same actions.
        bar = tqdm(total=config.max_depth, initial=depth, desc="backward sampling", unit="depth", disable=not progress)
        while True:
            in_region = int(sum(bool(s["in_start_region"]) for s in seeds))
            if in_region >= needed:
                break
            if depth >= config.max_depth:
                raise NoStartRegionError(
                    f"backward sampling reached max_depth={config.max_depth} with {in_region}/{len(seeds)} seeds in the "
                    f"start region (needed {needed}); raise --max-depth or --action-scale, or check the expert"
                )
            rng = np.random.default_rng([config.seed, depth])
            children = []
            for seed, node in zip(seeds, seed_nodes):
                actions = rng.uniform(-config.action_scale, config.action_scale, size=(config.num_children, 6))
                if pool is None:
                    res = sampler.children(_unflatten(sampler, seed["state"]), actions)
                else:
                    parts = np.array_split(actions, config.workers)
                    outs = pool.map(_worker_children, [(seed["state"], p) for p in parts if len(p)])
                    res = {k: np.concatenate([o[k] for o in outs]) for k in outs[0]}
                res["parent"] = np.full(len(actions), node)
                children.append(res)
                bar.set_postfix(children=config.num_children * len(seeds), in_start=in_region)
            merged = {k: np.concatenate([c[k] for c in children]) for k in children[0]}
            # Expert-guided progress measure: closest end-effector pose to the expert d+1 steps back.
            ref = expert.tcp_poses[max(goal_index - (depth + 1), 0)]
            dist = pose_distance(merged["tcp_pose"], ref, config.rotation_weight)
            chosen = np.argsort(dist, kind="stable")[: config.num_seeds]
            depth += 1
            seed_nodes = _append_depth(partial, merged, depth, chosen)
            seeds = [dict(state=merged["state"][i], in_start_region=merged["in_start_region"][i]) for i in chosen]
            bar.update(1)
        bar.close()
        with h5py.File(partial, "a") as f:
            f.attrs["complete"] = True
            f.attrs["final_depth"] = depth
        os.replace(partial, out_path)
        return str(out_path)
    finally:
        sampler.close()
        if pool is not None:
            pool.close()
            pool.join()


def _unflatten(sampler: ChildSampler, flat: np.ndarray) -> dict:
    from drem_maniskill.envs.insertion_base import _unflatten_like

    return _unflatten_like(sampler.unwrapped.get_state_dict(), torch.as_tensor(flat)[None])


def _open_or_resume(partial: Path, expert: ExpertTrajectory, config: SamplerConfig, sampler: ChildSampler, goal_index: int):
    header = dict(config=asdict(config), env_id=expert.env_id, env_kwargs=expert.env_kwargs,
                  episode_seed=expert.episode_seed, expert_length=goal_index)
    if partial.exists():
        try:
            with h5py.File(partial, "r") as f:
                if json.loads(f.attrs["header"]) == json.loads(json.dumps(header)):
                    depth = int(f.attrs["completed_depth"])
                    g = f[f"seeds/depth_{depth}"]
                    seeds = [dict(state=s, in_start_region=r) for s, r in zip(g["state"][()], g["in_start_region"][()])]
                    nodes = [int(n) for n in g["node"][()]]
                _truncate(partial)
                return depth, seeds, nodes
        except (OSError, KeyError):
            pass  # unreadable or from another config: start over
        partial.unlink()
    # Depth 0: the goal state, as the expert's last step recorded it.
    goal = _state_at(expert.states, goal_index)
    sampler.unwrapped.set_state_dict(_broadcast(goal, sampler.n))
    flat = sampler.unwrapped.get_state()[:1].cpu().numpy()
    in_region = bool(sampler.unwrapped.in_start_region()[0])
    root = dict(
        fixed_rgb=expert.last_obs["fixed_rgb"][None], wrist_rgb=expert.last_obs["wrist_rgb"][None],
        ft=expert.last_obs.get("ft", np.zeros((8, 6), np.float32))[None], tcp_pose=expert.tcp_poses[-1:],
        in_start_region=np.array([in_region]), state=flat, parent=np.array([-1]),
    )
    with h5py.File(partial, "w") as f:
        f.attrs["header"] = json.dumps(header)
        e = f.create_group("expert")
        for key, value in expert.first_obs.items():
            e.create_dataset(f"first/{key}", data=value)
        for key, value in expert.last_obs.items():
            e.create_dataset(f"last/{key}", data=value)
        e.create_dataset("tcp_pose", data=expert.tcp_poses)
    _append_depth(partial, root, 0, np.array([0]))
    return 0, [dict(state=flat[0], in_start_region=in_region)], [0]


def _append_depth(path: Path, data: dict, depth: int, chosen: np.ndarray) -> list:
    """Append one depth's nodes and its chosen seeds in one go; returns the seeds' node indices.

    ``completed_depth`` and ``node_count`` are written last, so a run interrupted half-way
    through a depth resumes from the previous one (extra rows are cut off on resume).
    """
    n = len(data["tcp_pose"])
    is_seed = np.zeros(n, bool)
    is_seed[chosen] = True
    rows = dict(
        fixed_rgb=data["fixed_rgb"].astype(np.uint8), wrist_rgb=data["wrist_rgb"].astype(np.uint8),
        ft=data["ft"].astype(np.float32), tcp_pose=data["tcp_pose"].astype(np.float32),
        depth=np.full(n, depth, np.int32), parent=data["parent"].astype(np.int64),
        in_start_region=data["in_start_region"].astype(bool), is_seed=is_seed,
    )
    with h5py.File(path, "a") as f:
        first = int(f.attrs.get("node_count", 0))
        for key, value in rows.items():
            if key not in f:
                f.create_dataset(key, data=value, maxshape=(None, *value.shape[1:]), chunks=(min(64, max(n, 1)), *value.shape[1:]),
                                 compression="gzip" if value.dtype == np.uint8 else None)
            else:
                f[key].resize(first + n, axis=0)
                f[key][first:] = value
        nodes = [first + int(i) for i in chosen]
        g = f.require_group(f"seeds/depth_{depth}")
        for key in list(g.keys()):
            del g[key]
        g.create_dataset("state", data=data["state"][chosen])
        g.create_dataset("in_start_region", data=data["in_start_region"][chosen].astype(bool))
        g.create_dataset("node", data=np.array(nodes, np.int64))
        f.attrs["node_count"] = first + n
        f.attrs["completed_depth"] = depth
    return nodes


def _truncate(path: Path) -> None:
    with h5py.File(path, "a") as f:
        count = int(f.attrs["node_count"])
        for key in DATASET_KEYS:
            if key in f and f[key].shape[0] > count:
                f[key].resize(count, axis=0)
