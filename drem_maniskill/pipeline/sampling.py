"""Backward sampling into a task progress tree (Section III-A of the paper).

Starting from the goal state ``s_G`` (the expert trajectory's last state), at depth ``d`` every
seed state gets ``M`` random actions, each applied from the restored seed state; the children
are recorded with depth ``d + 1`` and their parent. The next seeds are chosen by the progress
measure; the paper's expert-guided measure (``N = 1``) keeps the child whose end-effector pose
is closest to the expert's pose ``d + 1`` steps before the goal, and ``N > 1`` keeps the ``N``
closest. Sampling stops once at least ``N * delta`` seeds lie in the task's start region, or
fails with a clear error at ``max_depth``.

The expert trajectory is read in ManiSkill's format (``RecordEpisode``'s .h5 + .json): only
its observations (the first and last ones, for the reward's normalisation) and its environment
states (the goal state, and the end-effector poses the progress measure compares with) are
used, never its actions.

Any ManiSkill env works (``drem_maniskill.envs.adapter``): on our tasks the tree holds both
cameras and the F/T history; on a stock task (``PegInsertionSide-v1``, ...) its cameras
(``base_camera`` as ``fixed``, ``hand_camera`` as ``wrist``) and zeros for F/T. Where the robot
has a gripper, the measure also compares the gripper opening with the expert's, so the tree
opens the gripper where the expert had it open (the stock tasks start with the part on the
table).

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

import gymnasium as gym
import h5py
import numpy as np
import torch
from mani_skill.utils.geometry.rotation_conversions import quaternion_invert, quaternion_multiply, quaternion_to_axis_angle

from drem_maniskill.envs import check_env_id
from drem_maniskill.envs.adapter import adapter_for
from drem_maniskill.pipeline.dataset import face_entry_depth, in_opening
from drem_maniskill.utils.cameras import camera_roles
from drem_maniskill.utils.progress import progress_bar
from drem_maniskill.utils.state import broadcast_state, first_leaf, state_at

DATASET_KEYS = ("fixed_rgb", "wrist_rgb", "ft", "tcp_pose", "colors", "placement", "tip_in_socket", "depth", "parent",
                "in_start_region", "is_seed")


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
    """Random arm actions are uniform in [-action_scale, action_scale] (normalised action space); gripper ones always in [-1, 1]."""
    expert_step_scale: float = 0.0
    """When > 0, the arm actions at each depth span this many times the expert's own step there (its end-effector
    move between the states d and d + 1 before the goal), clipped to [min_action_scale, action_scale]: fine where
    the expert moves slowly (near the opening), the whole range where it moves fast. 0: the paper's fixed range."""
    min_action_scale: float = 0.05
    rotation_weight: float = 0.05
    """Metres per radian when comparing end-effector poses with the expert's."""
    seed: int = 0
    episode: int = 0
    """Which episode of the expert file to use."""
    workers: int = 1
    """Worker processes, each with its own env (children of one seed are split among them)."""
    gripper_weight: float = 1.0
    """Metres per metre of finger opening when comparing with the expert (robots with a gripper)."""
    start_radius: float = 0.03
    """Envs without a start-region predicate: within this distance of the expert's first TCP position."""
    randomize_colors: bool = True
    """Each child gets freshly drawn part and socket colours (tasks that have them; recorded in ``colors``), as the
    paper's sampling does and every reset of the task does: the image encoder must not learn one colour pair."""
    randomize_placement: bool = True
    """Each child's scene is moved as a whole to a freshly drawn socket placement (x, y, yaw, as the task's resets
    draw it; recorded in ``placement``): the robot moves with the socket, so the step replays the same in the
    socket's frame. Not in the paper, whose hole stays put; our tasks place the socket anew at every reset, and a
    tree of one placement teaches a reward that reads where the socket is, not how far the part is from it."""
    outward_depth: int = 0
    """Depths sampled past the start region, away from the expert's path (not in the paper; 0: off). The paper's tree
    is a tube around the expert, so a reward trained on it values states off the tube arbitrarily, and SAC found
    such states that it pays like an insertion (the part pressed on the floor beside the socket). Each outward
    lineage keeps the child that went farthest along its own direction (``outward_directions``), so the tree gains
    states beside and below the start region, labelled by their depth: farther from the goal than the start."""
    outward_lineages: int = 12
    """Outward directions: azimuths spread evenly, elevations alternating over ``outward_elevations``."""
    outward_children: int = 100
    """Random actions (full range) per outward seed and depth."""
    outward_elevations: tuple = (0.0, -35.0, -60.0)
    """Degrees above the horizontal of the outward directions (negative: downwards, towards the floor)."""
    face_depth: int = 0
    """Depths of the face phase (not in the paper; 0: off), sampled after the others on our tasks. The backward
    phase's children of the seed at the opening land anywhere on the socket's face within a random action of it,
    all one depth from that seed, so the reward learns no lead along the face to the opening (docs/drem.md). Each
    face lineage starts at that seed and keeps the child that slid farthest along its own direction, pressing on
    the face, a few millimetres per depth: the part on the face is labelled by how far it has slid from the opening."""
    face_lineages: int = 8
    """Face directions: azimuths spread evenly, all at ``face_elevation``."""
    face_children: int = 60
    """Random actions per face seed and depth."""
    face_step: float = 0.0015
    """Metres: the arm actions of the face phase span this much end-effector travel (the farthest child moves about this far)."""
    face_elevation: float = -30.0
    """Degrees above the horizontal of the face directions (negative: pressing down on the face as it slides)."""
    side_depth: int = 0
    """Depths of the side phase (not in the paper; 0: off; needs the face phase): each face lineage goes on from its
    last seed, over the face's edge and down beside the socket's block, keeping the child farthest along its direction
    at ``side_elevation``. SAC trained on a USB reward found the part lowered along the block's side, which the tree
    held almost no node of and the reward paid like an insertion (docs/drem.md, "The side phase"). Side step ``k``
    is labelled ``entry + face_depth + k``: farther from the goal than the face it left."""
    side_children: int = 60
    """Random actions per side seed and depth."""
    side_step: float = 0.004
    """Metres of end-effector travel the side phase's arm actions span."""
    side_elevation: float = -60.0
    """Degrees above the horizontal of the side directions (steeply down, over the edge and along the side)."""
    push_children: int = 0
    """Full-range random actions from every face and side seed (not in the paper; 0: off), labelled one depth past
    their seed and never seeds themselves. Lineage steps of a few millimetres press lightly (the face and side nodes
    read under 20 N at the wrist), so the only hard presses in a tree were the goal's children pushing on the
    opening's floor, and a reward trained on it paid a part pushed hard on the face or against the block's side
    like an insertion (docs/drem.md, "The side phase"). These children push the part into the face, the edge and
    the side with tens of newtons, labelled where they are: as far from the goal as the seed they left, plus one.
    Those that fall into the opening are not kept: they may be a step from the goal."""
    turn_depth: int = 0
    """Depths of the turn phase (not in the paper; 0: off; needs the face phase): lineages that turn the part about its
    axis and tilt it, near the opening. Every other phase keeps the part upright there (the face and side lineages
    penalise turning, the backward phase's steps near the goal are a fraction of the rotation range), so a reward
    trained on them values a turned part near the opening arbitrarily, and SAC on the GF USB reward hovered 8 mm off
    the axis turned 55 deg, paid 0.94 against 0.985 for an insertion, where the same place upright read 0.32
    (docs/drem.md, "The turn phase"). Each lineage starts at a seed near the opening (``TURN_HOVER_DEPTHS`` above it,
    ``TURN_FACE_STEPS`` along the face lineages) and keeps the child that turned farthest about its own axis; step
    ``k`` is labelled the seed's label plus ``k``: one step per rotation step of the controller."""
    turn_lineages: int = 2
    """Turn lineages per seed: rotation axes ``turn_tilt`` from the vertical, turning one way and the other."""
    turn_children: int = 24
    """Random actions per turn seed and depth: the rotation over the whole range, the translation within ``face_step``."""
    turn_tilt: float = 20.0
    """Degrees between a turn lineage's rotation axis and the vertical: mostly turning about the part's axis, partly tilting."""
    goal_presses: int = 0
    """Random actions from the goal state pushing down over the whole range (not in the paper; 0: off),
    labelled depth 1 and never seeds. A demo that descends slowly ends as soon as the part is far enough in, before
    it reaches the opening's floor, and its goal's children (small moves, ``expert_step_scale``) barely touch the
    floor, while a policy that inserts goes on pushing (the examination's at 39-84 N): a tree without such presses
    put a pressed insertion far from the goal (docs/drem.md, "A slower entry as well"). These children push the
    inserted part down with up to the arm's full step (sideways and twisting within the goal's own children's range):
    still inserted, one step from the goal."""

    @classmethod
    def preset(cls, name: str, **overrides) -> "SamplerConfig":
        """``paper`` (M = 500) or ``quick`` (M = 24, for minutes-long runs)."""
        presets = {"paper": {}, "quick": dict(num_children=24), "tiny": dict(num_children=4, max_depth=40)}
        if name not in presets:
            raise ValueError(f"unknown sampler preset {name!r}; choose one of {list(presets)}")
        return cls(**{**presets[name], **overrides})


def outward_directions(config: SamplerConfig) -> np.ndarray:
    """Unit vectors ``[outward_lineages, 3]`` (world frame at the expert's placement) the outward lineages move along."""
    k = config.outward_lineages
    azimuth = 2 * np.pi * np.arange(k) / k
    elevation = np.deg2rad(np.asarray(config.outward_elevations, float))[np.arange(k) % len(config.outward_elevations)]
    return np.stack([np.cos(azimuth) * np.cos(elevation), np.sin(azimuth) * np.cos(elevation), np.sin(elevation)], -1)


def face_directions(config: SamplerConfig, elevation_deg: Optional[float] = None) -> np.ndarray:
    """Unit vectors ``[face_lineages, 3]`` (world frame at the expert's placement) the face lineages slide along
    (at ``elevation_deg``, default ``face_elevation``; the side phase's at ``side_elevation``)."""
    azimuth = 2 * np.pi * np.arange(config.face_lineages) / config.face_lineages
    elevation = np.deg2rad(config.face_elevation if elevation_deg is None else elevation_deg)
    return np.stack([np.cos(azimuth) * np.cos(elevation), np.sin(azimuth) * np.cos(elevation),
                     np.full(config.face_lineages, np.sin(elevation))], -1)


def turn_axes(config: SamplerConfig, origins: int) -> np.ndarray:
    """Unit rotation axes ``[origins * turn_lineages, 3]`` (world frame at the expert's placement) of the turn lineages.

    Lineage ``l`` of origin ``o``: ``turn_tilt`` from the vertical, turning about +z for even ``l`` and -z for odd,
    tilting towards an azimuth that differs between origins (golden-angle steps), so the tree sees many tilts.
    """
    lineages = np.arange(origins * config.turn_lineages)
    azimuth = 2 * np.pi * (lineages // config.turn_lineages * 0.381966 + lineages % config.turn_lineages / config.turn_lineages)
    tilt = np.deg2rad(config.turn_tilt)
    sign = np.where(lineages % 2 == 0, 1.0, -1.0)
    return np.stack([np.sin(tilt) * np.cos(azimuth), np.sin(tilt) * np.sin(azimuth), sign * np.cos(tilt)], -1)


TURN_HOVER_DEPTHS = (0, 2, 4)  # the turn lineages start at the backward seeds this many depths past the entry (above it)
TURN_FACE_STEPS = (2, 5)  # and at these steps of every face lineage (3 and 7.5 mm from the opening at 1.5 mm a step)


FACE_SEED_HEIGHT = -0.0002  # m: a face seed's tip is above this, on or over the face, not caught in the opening's mouth
# (a lineage from the USB entry seed stayed 0.4-0.5 mm in the mouth for all 8 face steps with -0.5 mm; stop 23)


class NoStartRegionError(RuntimeError):
    """The tree reached ``max_depth`` before enough seeds were in the start region."""


# ---------------------------------------------------------------------------- expert input
@dataclass
class ExpertTrajectory:
    """The parts of a recorded expert episode that DREM uses (no actions)."""

    env_id: str
    env_kwargs: dict
    episode_seed: Optional[int]
    camera_map: dict  # modality -> camera uid of the recorded observations
    first_obs: dict  # {modality}_rgb (and ft) of step 0
    last_obs: dict  # of step T
    states: dict = field(default_factory=dict)  # env states, every leaf [T + 1, ...]

    @property
    def length(self) -> int:
        """Number of recorded states (steps + 1)."""
        return len(first_leaf(self.states))


def _read_tree(group) -> dict:
    out = {}
    for key, value in group.items():
        out[key] = _read_tree(value) if isinstance(value, h5py.Group) else value[()]
    return out


def _cameras_in(sensor_data) -> dict:
    """Modality -> camera uid among recorded cameras (``utils.cameras.camera_roles``, as for a live env)."""
    return camera_roles([u for u in sensor_data.keys() if "rgb" in sensor_data[u]])


def load_expert(h5_path: str, episode: int = 0) -> ExpertTrajectory:
    """Read one episode of a ManiSkill trajectory file (``.h5`` with its ``.json`` beside it)."""
    h5_path = Path(h5_path)
    json_path = h5_path.with_suffix(".json")
    if not h5_path.exists():
        raise FileNotFoundError(f"expert trajectory {h5_path} not found; record one with `drem-maniskill record-expert`")
    if not json_path.exists():
        raise FileNotFoundError(f"{json_path} (the metadata RecordEpisode writes beside {h5_path.name}) not found")
    try:
        meta = json.loads(json_path.read_text())
    except json.JSONDecodeError as err:
        raise ValueError(f"{json_path} is not valid JSON ({err}); re-record the expert") from err
    episodes = meta.get("episodes", [])
    if episode >= len(episodes):
        raise ValueError(f"{h5_path} has {len(episodes)} episodes; episode {episode} does not exist")
    ep = episodes[episode]
    try:
        with h5py.File(h5_path, "r") as f:
            traj = f[f"traj_{ep.get('episode_id', episode)}"]
            if "env_states" not in traj:
                raise ValueError(f"{h5_path} has no env_states; record with RecordEpisode(record_env_state=True)")
            obs = traj["obs"] if "obs" in traj else {}
            cams = _cameras_in(obs["sensor_data"]) if "sensor_data" in obs else {}
            if not cams:
                raise ValueError(
                    f"{h5_path} has no camera images in its observations: record the expert with obs_mode='rgb' "
                    "(drem-maniskill record-expert does)"
                )
            states = _read_tree(traj["env_states"])
            images = {m: obs[f"sensor_data/{uid}/rgb"] for m, uid in cams.items()}
            ft = obs["extra/ft"][()] if "extra" in obs and "ft" in obs["extra"] else None

            def pick(i):
                out = {f"{m}_rgb": images[m][i] for m in images}
                if ft is not None:
                    out["ft"] = ft[i]
                return out

            first, last = pick(0), pick(-1)
    except OSError as err:
        raise ValueError(f"cannot read {h5_path}: {err}. Is it a complete HDF5 file? Re-record it.") from err
    kwargs = dict(meta["env_info"].get("env_kwargs", {}))
    return ExpertTrajectory(
        env_id=meta["env_info"]["env_id"], env_kwargs=kwargs, episode_seed=ep.get("episode_seed"),
        camera_map=cams, first_obs=first, last_obs=last, states=states,
    )


# ---------------------------------------------------------------------------- children
def _batch_rows(values: np.ndarray, start: int, n: int) -> np.ndarray:
    """Rows ``start`` to ``start + n`` of ``values``, the last one repeated to fill a batch of ``n`` envs."""
    rows = np.asarray(values[start : start + n])
    return np.concatenate([rows, np.repeat(rows[-1:], n - len(rows), 0)])


class ChildSampler:
    """An env that restores a seed state and applies random actions, in batches of ``num_envs``."""

    def __init__(self, env_id: str, env_kwargs: dict, episode_seed: Optional[int], expert_first_ee=None,
                 start_radius: float = 0.03):
        kwargs = {**env_kwargs, "obs_mode": "rgb", "render_mode": None}
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
            raise ValueError(f"pushing down needs an end-effector delta arm controller (pd_ee_delta_pose), not {name or controller}")
        return int((getattr(controller, "action_mapping", {}) or {}).get("arm", (0, 0))[0]) + 2

    @property
    def rotation_dims(self) -> list:
        """The action dims that turn the end effector (a ``pd_ee_delta_pose`` arm controller's rotation)."""
        controller = self.unwrapped.agent.controller
        arm = getattr(controller, "controllers", {}).get("arm")
        if "EEPose" not in (type(arm).__name__ if arm is not None else ""):
            raise ValueError(f"turning needs an end-effector delta pose arm controller (pd_ee_delta_pose), not {arm or controller}")
        first = int((getattr(controller, "action_mapping", {}) or {}).get("arm", (0, 0))[0])
        return [first + 3, first + 4, first + 5]

    @property
    def translation_limit(self) -> float:
        """Metres of end-effector travel a full-scale arm action asks for (the controller's ``pos_upper``)."""
        arm = getattr(self.unwrapped.agent.controller, "controllers", {}).get("arm")
        limit = getattr(getattr(arm, "config", None), "pos_upper", None)
        return float(np.max(limit)) if limit is not None else 1.0

    def random_colors(self, rng: np.random.Generator, count: int) -> Optional[np.ndarray]:
        """``count`` part and socket colours ``[count, 6]`` drawn as the task's resets draw them, or None without colours."""
        if not self.adapter.colorable:
            return None
        return rng.uniform(*self.unwrapped.color_range, size=(count, 6))

    def random_placements(self, rng: np.random.Generator, count: int) -> Optional[np.ndarray]:
        """``count`` socket placements ``[count, 3]`` drawn as the task's resets draw them, or None where there are none."""
        if not self.adapter.placeable:
            return None
        return self.unwrapped.random_socket_placements(rng, count)

    def children(self, seed_state: dict, actions: np.ndarray, colors: Optional[np.ndarray] = None,
                 placements: Optional[np.ndarray] = None) -> dict:
        """Apply each action from ``seed_state`` (each child in its row of ``colors`` and ``placements``); observations, start flags, states.

        ``tcp_pose`` and ``ee`` are given at the expert's socket placement, so that they compare
        with the expert's whatever placement a child was moved to.
        """
        out = {k: [] for k in ("fixed_rgb", "wrist_rgb", "ft", "tcp_pose", "ee", "in_start_region", "state", "colors",
                               "placement", "tip_in_socket")}
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
            for m, image in self.adapter.images(obs).items():
                out[f"{m}_rgb"].append(image[:k].cpu().numpy())
            ft = self.adapter.ft()
            out["ft"].append(ft[:k].cpu().numpy() if ft is not None else np.zeros((k, 8, 6), np.float32))
            ee = self.adapter.ee_state_at(self.reference_placement)[:k].cpu().numpy()
            out["tcp_pose"].append(ee[:, :7])
            out["ee"].append(ee)
            out["in_start_region"].append(self.in_start_region()[:k].cpu().numpy())
            out["state"].append(self.adapter.flatten(self.adapter.get_state())[:k].cpu().numpy())
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


def _worker_init(env_id, env_kwargs, episode_seed, expert_first_ee, start_radius):
    global _WORKER
    torch.set_num_threads(1)
    _WORKER = ChildSampler(env_id, env_kwargs, episode_seed, expert_first_ee, start_radius)


def _worker_children(args):
    flat_state, actions, colors, placements = args
    return _WORKER.children(_WORKER.adapter.unflatten(flat_state), actions, colors, placements)


def pose_distance(a: np.ndarray, b: np.ndarray, rotation_weight: float, gripper_weight: float = 0.0) -> np.ndarray:
    """Distance between end-effector states ``[.., 7]`` or ``[.., 8]`` (pose, gripper width).

    Position L2 plus the weighted rotation angle, plus the weighted gripper-width difference
    when both carry one.
    """
    pos = np.linalg.norm(a[..., :3] - b[..., :3], axis=-1)
    dot = np.abs(np.sum(a[..., 3:7] * b[..., 3:7], axis=-1)).clip(0, 1)
    dist = pos + rotation_weight * 2 * np.arccos(dot)
    if gripper_weight and a.shape[-1] > 7 and b.shape[-1] > 7:
        dist = dist + gripper_weight * np.abs(a[..., 7] - b[..., 7])
    return dist


def action_scale_at(depth: int, expert_ee: np.ndarray, config: SamplerConfig, translation_limit: float) -> float:
    """The arm action range for the children of depth ``depth`` (``SamplerConfig.expert_step_scale``)."""
    if config.expert_step_scale <= 0:
        return config.action_scale
    goal = len(expert_ee) - 1
    a, b = max(goal - depth, 0), max(goal - depth - 1, 0)
    step = float(np.linalg.norm(expert_ee[a, :3] - expert_ee[b, :3]))
    return float(np.clip(config.expert_step_scale * step / translation_limit, config.min_action_scale, config.action_scale))


# ---------------------------------------------------------------------------- the tree
def backward_sample(expert_path: str, out_path: str, config: SamplerConfig = SamplerConfig(), progress: bool = True) -> str:
    """Build the task progress tree from an expert trajectory; returns the dataset's path."""
    out_path = Path(out_path)
    out_path.parent.mkdir(parents=True, exist_ok=True)
    partial = out_path.with_name(out_path.name + ".partial")
    expert = load_expert(expert_path, config.episode)
    goal_index = expert.length - 1

    sampler = ChildSampler(expert.env_id, expert.env_kwargs, expert.episode_seed, start_radius=config.start_radius)
    missing = [m for m, uid in sampler.adapter.camera_map.items() if expert.camera_map.get(m) != uid]
    if missing:
        sampler.close()
        raise ValueError(
            f"{expert_path} recorded cameras {expert.camera_map}, but {expert.env_id} samples {sampler.adapter.camera_map}; "
            "record the expert with the same env and sensor configs"
        )
    if config.push_children > 0 and config.face_depth <= 0:
        sampler.close()
        raise ValueError("the push children (--push-children) start from the face and side lineages' seeds: give --face-depth too")
    if config.turn_depth > 0 and config.face_depth <= 0:
        sampler.close()
        raise ValueError("the turn phase (--turn-depth) starts from the face lineages' seeds among others: give --face-depth too")
    if config.side_depth > 0 and config.face_depth <= 0:
        sampler.close()
        raise ValueError("the side phase (--side-depth) goes on from the face phase's lineages: give --face-depth too")
    if config.face_depth > 0 and sampler.adapter.tip_in_socket() is None:
        sampler.close()
        raise ValueError(f"the face phase (--face-depth) needs one of our insertion tasks, which know where the part's "
                         f"tip is on the socket; {expert.env_id} does not: sample it with --face-depth 0")
    # The measure compares with the expert's end-effector states, read from its env states
    # (not its observations), so any demo with env_states works.
    expert_ee = sampler.expert_ee_states(expert.states)
    sampler.expert_first_ee = expert_ee[0]
    gripper_weight = config.gripper_weight if sampler.adapter.gripper_idx else 0.0
    pool = None
    if config.workers > 1:
        import multiprocessing as mp

        pool = mp.get_context("spawn").Pool(
            config.workers, initializer=_worker_init,
            initargs=(expert.env_id, expert.env_kwargs, expert.episode_seed, expert_ee[0], config.start_radius),
        )
    try:
        depth, seeds, seed_nodes = _open_or_resume(partial, expert, expert_ee, config, sampler, goal_index)
        needed = math.ceil(config.num_seeds * config.delta)
        if _start_depth(partial) is not None:
            needed = 0  # resuming the outward phase: the start region was reached already
        bar = progress_bar(total=config.max_depth, initial=depth, desc="backward sampling", unit="depth", enabled=progress)
        while True:
            in_region = int(sum(bool(s["in_start_region"]) for s in seeds))
            if in_region >= needed:
                break
            if depth >= config.max_depth:
                raise NoStartRegionError(
                    f"backward sampling reached max_depth={config.max_depth} with {in_region}/{len(seeds)} seeds in the "
                    f"start region (needed {needed}); raise --max-depth or --action-scale, or check the expert"
                )
            scale = action_scale_at(depth, expert_ee, config, sampler.translation_limit)
            merged = _children_of(sampler, pool, config, seeds, seed_nodes, depth, config.num_children, scale)
            bar.set_postfix(children=config.num_children * len(seeds), in_start=in_region)
            # Expert-guided progress measure: closest end-effector state to the expert d+1 steps back.
            ref = expert_ee[max(goal_index - (depth + 1), 0)]
            dist = pose_distance(merged["ee"], ref, config.rotation_weight, gripper_weight)
            chosen = np.argsort(dist, kind="stable")[: config.num_seeds]
            depth += 1
            seed_nodes = _append_depth(partial, merged, depth, chosen)
            seeds = _seeds_at(merged, chosen)
            bar.update(1)
        bar.close()
        start_depth = _mark_start_depth(partial, depth)
        if config.outward_depth > 0:
            depth, seeds = _sample_outward(partial, sampler, pool, config, start_depth, depth, seeds, seed_nodes, progress)
        if config.face_depth > 0:
            _sample_face(partial, sampler, pool, config, start_depth, progress)
        if config.side_depth > 0:
            _sample_face(partial, sampler, pool, config, start_depth, progress, side=True)
        if config.push_children > 0:
            _sample_push(partial, sampler, pool, config, progress)
        if config.turn_depth > 0:
            _sample_turn(partial, sampler, pool, config, start_depth, progress)
        if config.goal_presses > 0:
            _sample_goal_presses(partial, sampler, pool, config, action_scale_at(0, expert_ee, config, sampler.translation_limit))
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



def _children_of(sampler: "ChildSampler", pool, config: SamplerConfig, seeds: list, seed_nodes: list, depth: int,
                 num_children: int, scale: float, stream: int = 0, down: bool = False, turn: bool = False) -> dict:
    """``num_children`` children of every seed, each with fresh colours and placement where configured, merged in seed order.

    ``down``: the arm's vertical action component is drawn downwards over the whole range (``ChildSampler.vertical_dim``),
    the others within ``scale``. ``turn``: the arm's rotation components over the whole range (``ChildSampler.rotation_dims``).
    """
    # The random streams are functions of the depth, so a resumed run draws the same actions; colours and
    # placements have streams of their own, so turning them off leaves the actions as they were.
    rng = np.random.default_rng([config.seed, depth] + ([stream] if stream else []))
    color_rng = np.random.default_rng([config.seed, depth, 1 + 3 * stream])
    place_rng = np.random.default_rng([config.seed, depth, 2 + 3 * stream])
    children = []
    for seed, node in zip(seeds, seed_nodes):
        actions = sampler.random_actions(rng, num_children, scale)
        if down:
            actions[:, sampler.vertical_dim] = -np.abs(actions[:, sampler.vertical_dim]) / scale * config.action_scale
        if turn:
            actions[:, sampler.rotation_dims] = actions[:, sampler.rotation_dims] / scale * config.action_scale
        colors = sampler.random_colors(color_rng, num_children) if config.randomize_colors else None
        places = sampler.random_placements(place_rng, num_children) if config.randomize_placement else None
        if pool is None:
            res = sampler.children(sampler.adapter.unflatten(seed["state"]), actions, colors, places)
        else:
            parts = np.array_split(np.arange(len(actions)), config.workers)
            outs = pool.map(_worker_children, [(seed["state"], actions[p], None if colors is None else colors[p],
                                                None if places is None else places[p])
                                               for p in parts if len(p)])
            res = {k: np.concatenate([o[k] for o in outs]) for k in outs[0]}
        res["parent"] = np.full(len(actions), node)
        children.append(res)
    return {k: np.concatenate([c[k] for c in children]) for k in children[0]}


def _seeds_at(data, rows) -> list:
    """The seeds the samplers take from ``rows`` of ``data`` (a depth's merged children, or a ``seeds/`` group)."""
    return [dict(state=data["state"][i], in_start_region=data["in_start_region"][i]) for i in rows]


def _read_seeds(group) -> tuple[list, list]:
    """The seeds of an open ``seeds/<name>`` HDF5 group, as the samplers take them, and their node indices."""
    seeds = [dict(state=s, in_start_region=r) for s, r in zip(group["state"][()], group["in_start_region"][()])]
    return seeds, [int(n) for n in group["node"][()]]


def _start_depth(path: Path) -> Optional[int]:
    """The depth at which the backward phase reached the start region, once it has (else None)."""
    with h5py.File(path, "r") as f:
        value = f.attrs.get("start_depth")
    return None if value is None else int(value)


def _mark_start_depth(path: Path, depth: int) -> int:
    """Record (once) the depth that reached the start region; returns it."""
    known = _start_depth(path)
    if known is not None:
        return known
    with h5py.File(path, "a") as f:
        f.attrs["start_depth"] = depth
    return depth


def _farthest_along(ee: np.ndarray, origin: np.ndarray, directions: np.ndarray,
                    penalty: Optional[np.ndarray] = None) -> np.ndarray:
    """Row of each lineage's child that went farthest from ``origin`` along the lineage's direction, less ``penalty``.

    ``ee`` ``[lineages * children, >= 3]`` holds the children lineage by lineage (``_children_of``'s order): their
    end-effector poses, or, for the turn phase, their rotation vectors with ``directions`` the lineages' axes.
    """
    along = np.einsum("lcx,lx->lc", (ee[:, :3] - origin).reshape(len(directions), -1, 3), directions)
    if penalty is not None:
        along = along - penalty.reshape(along.shape)
    return np.arange(len(directions)) * along.shape[1] + along.argmax(1)


def _sample_outward(partial: Path, sampler: "ChildSampler", pool, config: SamplerConfig, start_depth: int, depth: int,
                    seeds: list, seed_nodes: list, progress: bool) -> tuple:
    """The outward phase (``SamplerConfig.outward_depth``): one lineage per direction, from the start-region seed."""
    directions = outward_directions(config)
    with h5py.File(partial, "r") as f:
        start_node = int(f[f"seeds/depth_{start_depth}/node"][0])
        origin = f["tcp_pose"][start_node][:3].astype(np.float64)
    if depth == start_depth:
        seeds, seed_nodes = [seeds[0]] * len(directions), [seed_nodes[0]] * len(directions)
    bar = progress_bar(total=config.outward_depth, initial=depth - start_depth, desc="outward sampling", unit="depth",
                       enabled=progress)
    while depth < start_depth + config.outward_depth:
        merged = _children_of(sampler, pool, config, seeds, seed_nodes, depth, config.outward_children, config.action_scale,
                              stream=3)
        chosen = _farthest_along(merged["ee"], origin, directions)
        depth += 1
        seed_nodes = _append_depth(partial, merged, depth, chosen)
        seeds = _seeds_at(merged, chosen)
        bar.update(1)
    bar.close()
    return depth, seeds


def _rotation_from(q: np.ndarray, q0: np.ndarray) -> np.ndarray:
    """Radians between quaternions ``q [n, 4]`` and ``q0 [4]``."""
    return 2 * np.arccos(np.clip(np.abs(q @ q0), 0.0, 1.0))


def _caught_penalty(tip: np.ndarray, side: bool) -> np.ndarray:
    """Metres off each lineage child's score: 1 plus 100 times how far in it is for a child caught in the opening, else 0.

    Face phase: caught below ``FACE_SEED_HEIGHT`` (in the opening's mouth); side phase: in the opening (``in_opening``).
    Never chosen while a child of its lineage is free, and a lineage whose children are all caught keeps the least
    deep, so it climbs out instead of staying in the mouth labelled as the face (stop 23: one of 8 USB lineages did).
    """
    if side:
        caught, depth = in_opening(tip), -tip[:, 2]
    else:
        caught, depth = tip[:, 2] < FACE_SEED_HEIGHT, FACE_SEED_HEIGHT - tip[:, 2]
    return np.where(caught, 1.0 + 100.0 * depth, 0.0)  # a millimetre deeper outweighs any lineage step


def _out_of_opening(merged: dict, chosen: np.ndarray) -> tuple:
    """``merged`` without the children in the opening (``in_opening``) other than ``chosen``; the chosen rows' new
    indices; how many were dropped.

    A lineage's or push child that went into the opening is labelled by where it started (the face or the side),
    while it may be a step from the goal: kept, it would teach the reward that the inside of the opening is far
    (stop 23: 882 such nodes of stop 22's side and push phases, labelled up to 29 where the entry is 12).
    """
    keep = ~in_opening(merged["tip_in_socket"])
    keep[chosen] = True
    return {k: v[keep] for k, v in merged.items()}, np.cumsum(keep)[chosen] - 1, int((~keep).sum())


def _sample_face(partial: Path, sampler: "ChildSampler", pool, config: SamplerConfig, start_depth: int,
                 progress: bool, side: bool = False) -> None:
    """The face phase (``SamplerConfig.face_depth``): lineages that slide the part over the face from the opening.

    Lineage ``l``'s seed at face step ``k`` is labelled ``entry + k``: ``k`` small moves from the seed
    at the opening, which is ``entry`` from the goal. The child kept is the one farthest along the
    lineage's direction, less ``rotation_weight`` metres per radian it turned, so the part stays upright,
    and out of the opening's mouth (``_caught_penalty``). Children that went into the opening are near the
    goal, not where their lineage is: they are not kept (``_out_of_opening``; counted in the group's
    ``dropped_in_opening``).

    ``side``: the side phase (``SamplerConfig.side_depth``), the same lineages going on from their last
    face seeds along ``side_elevation`` (over the edge and down beside the block), step ``k`` labelled
    ``entry + face_depth + k``.
    """
    entry = face_entry_depth(partial, start_depth)
    if side:
        name, total, children, step = "side", config.side_depth, config.side_children, config.side_step
        directions = face_directions(config, config.side_elevation)
        first, label0 = f"face_{config.face_depth}", entry + config.face_depth
    else:
        name, total, children, step = "face", config.face_depth, config.face_children, config.face_step
        directions = face_directions(config)
        first, label0 = f"depth_{entry}", entry
    lineages = len(directions)
    with h5py.File(partial, "r") as f:
        if side and int(f.attrs.get("face_completed", 0)) < config.face_depth:
            raise ValueError(f"{partial}: the side phase starts where the face phase ended, which is not complete")
        done = int(f.attrs.get(f"{name}_completed", 0))
        seeds, nodes = _read_seeds(f[f"seeds/{first}"] if done == 0 else f[f"seeds/{name}_{done}"])
        entry_node = int(f[f"seeds/depth_{entry}/node"][0])
        origin = f["tcp_pose"][entry_node][:3].astype(np.float64)
        upright = f["tcp_pose"][entry_node][3:7].astype(np.float64)
    if done == 0 and not side:
        seeds, nodes = seeds[:1] * lineages, nodes[:1] * lineages
    scale = float(np.clip(step / sampler.translation_limit, config.min_action_scale, config.action_scale))
    bar = progress_bar(total=total, initial=done, desc=f"{name} sampling", unit="depth", enabled=progress)
    for k in range(done, total):
        merged = _children_of(sampler, pool, config, seeds, nodes, label0 + k, children, scale, stream=5 if side else 4)
        penalty = config.rotation_weight * _rotation_from(merged["ee"][:, 3:7].astype(np.float64), upright)
        penalty += _caught_penalty(merged["tip_in_socket"].astype(np.float64), side)
        chosen = _farthest_along(merged["ee"], origin, directions, penalty)
        merged, chosen, dropped = _out_of_opening(merged, chosen)
        nodes = _append_depth(partial, merged, label0 + k + 1, chosen, group=f"{name}_{k + 1}",
                              counter=f"{name}_completed", count=k + 1, attrs={"dropped_in_opening": dropped})
        seeds = _seeds_at(merged, chosen)
        bar.update(1)
    bar.close()


def push_groups(config: SamplerConfig) -> list:
    """The seed groups the push children start from, in sampling order: ``face_1`` .. and ``side_1`` .."""
    return [f"face_{k}" for k in range(1, config.face_depth + 1)] + [f"side_{k}" for k in range(1, config.side_depth + 1)]


def _sample_push(partial: Path, sampler: "ChildSampler", pool, config: SamplerConfig, progress: bool) -> None:
    """The push children (``SamplerConfig.push_children``): full-range actions from each face and side seed.

    Group ``i`` of ``push_groups`` gets ``push_<i + 1>`` (no seeds), its children labelled one past the seed's depth;
    ``push_completed`` counts the groups done, so an interrupted run resumes at the next group.
    """
    groups = push_groups(config)
    with h5py.File(partial, "r") as f:
        done = int(f.attrs.get("push_completed", 0))
        if int(f.attrs.get("face_completed", 0)) < config.face_depth or int(f.attrs.get("side_completed", 0)) < config.side_depth:
            raise ValueError(f"{partial}: the push children start from the face and side seeds, which are not complete")
    bar = progress_bar(total=len(groups), initial=done, desc="push sampling", unit="group", enabled=progress)
    for i in range(done, len(groups)):
        with h5py.File(partial, "r") as f:
            seeds, nodes = _read_seeds(f[f"seeds/{groups[i]}"])
            depth = int(f["depth"][nodes[0]])
        merged = _children_of(sampler, pool, config, seeds, nodes, depth, config.push_children, config.action_scale, stream=6)
        merged, _, dropped = _out_of_opening(merged, np.zeros(0, np.int64))
        _append_depth(partial, merged, depth + 1, np.zeros(0, np.int64), group=f"push_{i + 1}",
                      counter="push_completed", count=i + 1, attrs={"dropped_in_opening": dropped})
        bar.update(1)
    bar.close()


def _rotation_vectors(q: np.ndarray, q0: np.ndarray) -> np.ndarray:
    """Rotation vectors ``[n, 3]`` (world frame, rad) turning quaternions ``q0 [n, 4]`` into ``q [n, 4]`` (wxyz)."""
    rel = quaternion_multiply(torch.as_tensor(q), quaternion_invert(torch.as_tensor(q0)))  # the short way round
    return quaternion_to_axis_angle(rel).numpy()


def turn_origins(path, config: SamplerConfig, start_depth: int) -> list:
    """The turn lineages' first seeds: ``(group of seeds/, index in it, label)`` each: the entry seed, the backward seeds
    ``TURN_HOVER_DEPTHS`` past it that are out of the opening, and the face lineages' seeds at ``TURN_FACE_STEPS``."""
    entry = face_entry_depth(path, start_depth)
    with h5py.File(path, "r") as f:
        # Above the opening: a backward seed past the entry may have gone back into it (a coarse tree's).
        hover = [d for d in TURN_HOVER_DEPTHS if entry + d <= start_depth
                 and (d == 0 or not in_opening(f["tip_in_socket"][[int(f[f"seeds/depth_{entry + d}/node"][0])]])[0])]
    groups = [(f"depth_{entry + d}", 0, entry + d) for d in hover]
    groups += [(f"face_{k}", i, entry + k) for k in TURN_FACE_STEPS if k <= config.face_depth for i in range(config.face_lineages)]
    return groups


def _sample_turn(partial: Path, sampler: "ChildSampler", pool, config: SamplerConfig, start_depth: int, progress: bool) -> None:
    """The turn phase (``SamplerConfig.turn_depth``): lineages that turn and tilt the part near the opening.

    Lineage ``l`` keeps, at each step, the child whose rotation from the lineage's first seed goes farthest along its
    axis (``turn_axes``), out of the opening (``_caught_penalty``, as the side phase); children that went into the
    opening are not kept (``_out_of_opening``). Step ``k``'s nodes are labelled their lineage's first label plus ``k``
    (kept per seed in the group's ``label`` attribute, so a resume goes on from them).
    """
    with h5py.File(partial, "r") as f:
        if int(f.attrs.get("face_completed", 0)) < config.face_depth:
            raise ValueError(f"{partial}: the turn phase starts from the face seeds, which are not complete")
        done = int(f.attrs.get("turn_completed", 0))
        origins = turn_origins(partial, config, start_depth)
        first = [f[f"seeds/{g}"] for g, _, _ in origins]
        start_nodes = np.array([int(g["node"][i]) for g, (_, i, _) in zip(first, origins)])
        start_q = f["tcp_pose"][()][np.repeat(start_nodes, config.turn_lineages), 3:7].astype(np.float64)
        if done == 0:
            seeds = [_seeds_at(g, [i])[0] for g, (_, i, _) in zip(first, origins)]
            seeds = [s for s in seeds for _ in range(config.turn_lineages)]
            nodes = list(np.repeat(start_nodes, config.turn_lineages))
            labels = np.repeat([label for _, _, label in origins], config.turn_lineages)
        else:
            seeds, nodes = _read_seeds(f[f"seeds/turn_{done}"])
            labels = np.asarray(f[f"seeds/turn_{done}"].attrs["label"])
    axes = turn_axes(config, len(origins))
    scale = float(np.clip(config.face_step / sampler.translation_limit, config.min_action_scale, config.action_scale))
    bar = progress_bar(total=config.turn_depth, initial=done, desc="turn sampling", unit="depth", enabled=progress)
    for k in range(done, config.turn_depth):
        merged = _children_of(sampler, pool, config, seeds, nodes, int(labels.min()), config.turn_children, scale,
                              stream=8, turn=True)
        turned = _rotation_vectors(merged["ee"][:, 3:7].astype(np.float64), np.repeat(start_q, config.turn_children, axis=0))
        # As the other lineages go farthest along a direction in space, these go farthest about their axes.
        chosen = _farthest_along(turned, np.zeros(3), axes, _caught_penalty(merged["tip_in_socket"].astype(np.float64), side=True))
        merged["label"] = np.repeat(labels + 1, config.turn_children)
        merged, chosen, dropped = _out_of_opening(merged, chosen)
        labels = labels + 1
        nodes = _append_depth(partial, merged, merged.pop("label"), chosen, group=f"turn_{k + 1}", counter="turn_completed",
                              count=k + 1, attrs={"dropped_in_opening": dropped, "label": labels})
        seeds = _seeds_at(merged, chosen)
        bar.update(1)
    bar.close()


def _sample_goal_presses(partial: Path, sampler: "ChildSampler", pool, config: SamplerConfig, scale: float) -> None:
    """The goal presses (``SamplerConfig.goal_presses``): actions pushing down from the goal, labelled depth 1.

    The vertical component spans the whole downward range; the others ``scale``, the goal's own children's range
    (full-range sideways and twisting actions lever the part up and out of a tight opening, far from the goal).

    Written as one group, ``goal_press`` (no seeds); ``goal_press_completed`` is set once it is, so a resume skips it.
    """
    with h5py.File(partial, "r") as f:
        if int(f.attrs.get("goal_press_completed", 0)):
            return
        seeds, nodes = _read_seeds(f["seeds/depth_0"])
    merged = _children_of(sampler, pool, config, seeds, nodes, 0, config.goal_presses, scale, stream=7, down=True)
    _append_depth(partial, merged, 1, np.zeros(0, np.int64), group="goal_press", counter="goal_press_completed", count=1)


# A run that gave up at max_depth resumes with a larger one; one sampled with 1 worker process goes on with 2 (the
# nodes sampled stay as they are; a child's step differs between worker layouts only by the sibling before it in
# PhysX's contact cache, 0.03-0.11 N, docs/drem.md), where a changed `workers` used to throw the partial tree away.
RESUMABLE_SAMPLER_FIELDS = ("max_depth", "workers")
# Phases a finished tree can gain: field -> the fields that must match once the phase has begun.
GROWABLE = {"side_depth": ("side_children", "side_step", "side_elevation"), "push_children": (), "goal_presses": (),
            "turn_depth": ("turn_lineages", "turn_children", "turn_tilt")}


def _resumable(saved: dict, now: dict) -> bool:
    """Whether a partial tree with header ``saved`` can be continued under ``now``: the same but for ``max_depth`` and
    ``workers``, or a tree without the side phase, the push children or the turn phase (``GROWABLE``) gaining them."""
    def strip(h):
        drop = RESUMABLE_SAMPLER_FIELDS + tuple(GROWABLE) + sum(GROWABLE.values(), ())
        return {**h, "config": {k: v for k, v in h.get("config", {}).items() if k not in drop}}
    old, new = saved.get("config", {}), now.get("config", {})
    for phase, same in GROWABLE.items():
        if old.get(phase, 0) > 0 and (old.get(phase) != new.get(phase) or any(old.get(k) != new.get(k) for k in same)):
            return False  # a phase once begun resumes only as it was
    return strip(saved) == strip(now)


def _open_or_resume(partial: Path, expert: ExpertTrajectory, expert_ee: np.ndarray, config: SamplerConfig,
                    sampler: ChildSampler, goal_index: int):
    header = dict(config=asdict(config), env_id=expert.env_id, env_kwargs=expert.env_kwargs,
                  episode_seed=expert.episode_seed, expert_length=goal_index, camera_map=sampler.adapter.camera_map,
                  has_ft=sampler.adapter.has_ft, action_dim=sampler.action_dim)
    if partial.exists():
        resumed = None
        try:
            with h5py.File(partial, "r") as f:
                if _resumable(json.loads(f.attrs["header"]), json.loads(json.dumps(header))):
                    depth = int(f.attrs["completed_depth"])
                    resumed = (depth, *_read_seeds(f[f"seeds/depth_{depth}"]))
        except (OSError, KeyError):
            pass  # unreadable: start over
        if resumed is not None:
            # Closed first: HDF5 will not open a file for writing that this process holds open for reading.
            _truncate(partial)
            with h5py.File(partial, "a") as f:
                f.attrs["header"] = json.dumps(header)  # a raised max_depth is the run's own from now on
            return resumed
        partial.unlink()  # from another config: start over
    # Depth 0: the goal state, as the expert's last step recorded it.
    goal = state_at(expert.states, goal_index)
    sampler.adapter.set_state(broadcast_state(goal, sampler.n))
    flat = sampler.adapter.flatten(sampler.adapter.get_state())[:1].cpu().numpy()
    in_region = bool(sampler.in_start_region()[0])
    root = {f"{m}_rgb": expert.last_obs[f"{m}_rgb"][None] for m in expert.camera_map}
    colors = sampler.adapter.colors()  # the expert episode's, from its seed
    if colors is not None:
        root["colors"] = colors[:1].numpy()
    placements = sampler.adapter.placements()
    if placements is not None:
        root["placement"] = placements[:1].cpu().numpy()
    tip = sampler.adapter.tip_in_socket()
    if tip is not None:
        root["tip_in_socket"] = tip[:1].cpu().numpy()
    root.update(
        ft=expert.last_obs.get("ft", np.zeros((8, 6), np.float32))[None], tcp_pose=expert_ee[-1:, :7],
        in_start_region=np.array([in_region]), state=flat, parent=np.array([-1]),
    )
    with h5py.File(partial, "w") as f:
        f.attrs["header"] = json.dumps(header)
        e = f.create_group("expert")
        for key, value in expert.first_obs.items():
            e.create_dataset(f"first/{key}", data=value)
        for key, value in expert.last_obs.items():
            e.create_dataset(f"last/{key}", data=value)
        e.create_dataset("tcp_pose", data=expert_ee[:, :7].astype(np.float32))
        e.create_dataset("ee_state", data=expert_ee.astype(np.float32))
    _append_depth(partial, root, 0, np.array([0]))
    return 0, [dict(state=flat[0], in_start_region=in_region)], [0]


def _append_depth(path: Path, data: dict, depth, chosen: np.ndarray, group: Optional[str] = None,
                  counter: str = "completed_depth", count: Optional[int] = None, attrs: Optional[dict] = None) -> list:
    """Append one depth's nodes (``depth``: their label, or one per node) and its chosen seeds in one go; returns the
    seeds' node indices.

    ``attrs`` go on the seeds' group (e.g. how many children were dropped).

    The seeds go to ``seeds/<group>`` (default ``depth_<depth>``). ``counter`` (``completed_depth``;
    the face phase keeps its own) and ``node_count`` are written last, so a run interrupted half-way
    through a depth resumes from the previous one (extra rows are cut off on resume).
    """
    n = len(data["tcp_pose"])
    is_seed = np.zeros(n, bool)
    is_seed[chosen] = True
    rows = {k: data[k].astype(np.uint8) for k in ("fixed_rgb", "wrist_rgb") if k in data}
    for key in ("colors", "placement", "tip_in_socket"):
        if key in data:
            rows[key] = data[key].astype(np.float32)
    rows.update(
        ft=data["ft"].astype(np.float32), tcp_pose=data["tcp_pose"].astype(np.float32),
        depth=np.broadcast_to(np.asarray(depth, np.int32), (n,)).copy(), parent=data["parent"].astype(np.int64),
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
        g = f.require_group(f"seeds/{group or f'depth_{depth}'}")
        for key in list(g.keys()):
            del g[key]
        g.create_dataset("state", data=data["state"][chosen])
        g.create_dataset("in_start_region", data=data["in_start_region"][chosen].astype(bool))
        g.create_dataset("node", data=np.array(nodes, np.int64))
        g.attrs.update(attrs or {})
        f.attrs["node_count"] = first + n
        f.attrs[counter] = depth if count is None else count
    return nodes


def _truncate(path: Path) -> None:
    with h5py.File(path, "a") as f:
        count = int(f.attrs["node_count"])
        for key in DATASET_KEYS:
            if key in f and f[key].shape[0] > count:
                f[key].resize(count, axis=0)
