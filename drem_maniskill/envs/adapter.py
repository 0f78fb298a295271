"""How the DREM pipeline reads an env: cameras, F/T, end-effector state, start region, states.

The backward sampler talks to an env only through ``EnvAdapter``, so the same pipeline runs on
our insertion tasks and on any ManiSkill task (``PegInsertionSide-v1``, ``PlugCharger-v1``, a
user's own). ``adapter_for(env)`` picks:

* **our tasks** (``InsertionEnv``): cameras ``fixed_camera`` / ``wrist_camera``, the wrist F/T
  history, the task's ``in_start_region()``, and states that already replay a step;
* **any other ManiSkill env**: its cameras in the roles of ``utils.cameras.camera_roles``
  (``base_camera`` as ``fixed``, ``hand_camera`` as ``wrist`` in ManiSkill's tabletop tasks),
  images only (no F/T sensor), and as start region "the end-effector within ``radius`` of the
  expert's first pose, gripper opening within 2 cm of the expert's".

States: ManiSkill's ``set_state_dict`` restores bodies and joints but not the joint drive
targets that the PD controllers hold, so a restored state does not replay the next step.
``get_state``/``set_state`` here add the drive targets (key ``drem_drive_targets``); our tasks
do this themselves (``task.drive_targets``).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable, Optional

import numpy as np
import torch

from drem_maniskill.envs.insertion_base import InsertionEnv
from drem_maniskill.utils.cameras import camera_images, camera_roles, env_cameras
from drem_maniskill.utils.state import flatten_state, scene_poses, unflatten_like

DRIVE_KEY = "drem_drive_targets"


@dataclass(frozen=True)
class SocketGeometry:
    """Where the opening is, in the socket frame (origin at the opening's centre on the top face, z up; metres)."""

    opening_radius: float
    """A tip below ``inserted_height`` and this close to the axis is in the opening."""
    inserted_height: float
    """A tip lower than this is in the opening or beside the socket's block."""
    face_seed_height: float
    """A tip above this is on or over the face, not caught in the opening's mouth."""
    socket_height: float
    """The top face's height above the floor."""

    def in_opening(self, tip) -> np.ndarray:
        """Bool ``[n]``: rows of tip positions ``[n, 3]`` (socket frame) that are in the opening."""
        tip = np.asarray(tip)
        return (tip[:, 2] < self.inserted_height) & (np.linalg.norm(tip[:, :2], axis=1) <= self.opening_radius)

    @classmethod
    def of_task(cls, task) -> Optional["SocketGeometry"]:
        """The geometry of an insertion task (class or instance), or None for any other env."""
        if not (isinstance(task, InsertionEnv) or (isinstance(task, type) and issubclass(task, InsertionEnv))):
            return None
        return cls(float(task.opening_radius), float(task.inserted_height), float(task.face_seed_height),
                   float(task.socket_height))


def socket_geometry_of(env_id: str) -> Optional[SocketGeometry]:
    """The socket geometry of a registered env id without making the env (None: not one of our insertion tasks)."""
    from mani_skill.utils.registration import REGISTERED_ENVS

    spec = REGISTERED_ENVS.get(env_id)
    return None if spec is None else SocketGeometry.of_task(spec.cls)


def camera_map_for(env) -> dict:
    """Role -> camera uid of ``env`` (``fixed`` always, ``wrist`` when it has a wrist camera)."""
    roles = camera_roles(env_cameras(env))
    if not roles:
        u = env.unwrapped
        raise ValueError(
            f"{u.spec.id if u.spec else type(u).__name__} has no camera; DREM needs at least one RGB camera "
            "(pass sensor_configs or a robot with a camera)"
        )
    return roles


def _gripper_joint_indices(env) -> list:
    names = [j.name for j in env.agent.robot.get_active_joints()]
    return [i for i, n in enumerate(names) if "finger" in n]


@dataclass
class EnvAdapter:
    """The DREM pipeline's view of one (unwrapped) ManiSkill env; every tensor is batched."""

    env: object
    camera_map: dict
    has_ft: bool
    start_fn: Optional[Callable] = None
    gripper_idx: list = field(default_factory=list)

    @property
    def env_id(self) -> str:
        """Registered id of the env."""
        return getattr(self.env, "env_id", None) or self.env.spec.id

    def images(self, obs) -> dict:
        """``{modality: [B, H, W, 3] uint8}`` from an observation, or rendered once if it has none."""
        images = camera_images(self.env, obs, self.camera_map.values())
        return {m: images[uid] for m, uid in self.camera_map.items()}

    @property
    def colorable(self) -> bool:
        """Whether the env's part and socket colours can be set (our tasks; not part of any state)."""
        return hasattr(self.env, "set_colors")

    def set_colors(self, colors) -> None:
        """Part and socket colours ``[num_envs, 6]`` (our tasks only)."""
        self.env.set_colors(colors)

    def colors(self) -> Optional[torch.Tensor]:
        """Part and socket colours ``[num_envs, 6]``, or None on an env without them."""
        return self.env.get_colors() if self.colorable else None

    @property
    def placeable(self) -> bool:
        """Whether the socket (and the robot with it) can be moved as a whole (our tasks)."""
        return hasattr(self.env, "place_socket")

    def placements(self) -> Optional[torch.Tensor]:
        """The socket's placement ``[num_envs, 3]`` (x, y, yaw), or None on an env without one."""
        return self.env.socket_placements() if self.placeable else None

    def place(self, placements) -> None:
        """Move the socket to ``placements`` ``[num_envs, 3]``, the robot rigidly with it (our tasks only)."""
        self.env.place_socket(placements)

    def ee_state_at(self, placement=None) -> torch.Tensor:
        """``ee_state()`` with its pose moved to where it would be with the socket at ``placement`` (None: as it is)."""
        ee = self.ee_state()
        if placement is None or not self.placeable:
            return ee
        return torch.cat([self.env.pose_at_placement(ee[:, :7], placement), ee[:, 7:]], dim=1)

    def tip_in_socket(self) -> Optional[torch.Tensor]:
        """The part tip's position in the socket frame ``[B, 3]`` (our tasks; for reports on the tree), else None."""
        return self.env.tip_pose_in_socket().p if isinstance(self.env, InsertionEnv) else None

    def socket_geometry(self) -> Optional[SocketGeometry]:
        """Where the opening is around the socket frame (our tasks), or None on an env without a socket."""
        return SocketGeometry.of_task(self.env)

    def ft(self) -> Optional[torch.Tensor]:
        """Wrist F/T history ``[B, H, 6]``, or None without our sensor."""
        return self.env.ft.buffer if self.has_ft else None

    def tcp_pose(self) -> torch.Tensor:
        """End-effector (TCP) pose ``[B, 7]`` (position, wxyz quaternion)."""
        return self.env.agent.tcp.pose.raw_pose

    def gripper_width(self) -> torch.Tensor:
        """Sum of the finger joint positions ``[B]`` (0 for a robot without fingers)."""
        if not self.gripper_idx:
            return torch.zeros(self.env.num_envs, device=self.env.device)
        return self.env.agent.robot.get_qpos()[:, self.gripper_idx].sum(-1)

    def ee_state(self) -> torch.Tensor:
        """``[B, 8]``: TCP pose and gripper width, what the expert-guided measure compares."""
        return torch.cat([self.tcp_pose(), self.gripper_width()[:, None]], dim=1)

    def in_start_region(self, expert_first: Optional[np.ndarray] = None, radius: float = 0.03) -> torch.Tensor:
        """Bool ``[B]``: the env's start-region predicate (or closeness to the expert's first state)."""
        if self.start_fn is not None:
            return self.start_fn(self.env)
        if expert_first is None:
            raise ValueError(f"{self.env_id} has no start-region predicate; pass the expert's first end-effector state")
        ref = torch.as_tensor(expert_first, dtype=torch.float32, device=self.env.device)
        ee = self.ee_state()
        near = torch.linalg.norm(ee[:, :3] - ref[:3], dim=1) <= radius
        return near & ((ee[:, 7] - ref[7]).abs() <= 0.02)

    def poses(self) -> torch.Tensor:
        """``scene_poses`` of the env's current state ``[B, D]``."""
        return scene_poses(self.env.get_state_dict())

    def get_state(self) -> dict:
        """A state dict that replays the next step when restored (drive targets included)."""
        state = self.env.get_state_dict()
        if not isinstance(self.env, InsertionEnv):
            state[DRIVE_KEY] = self.env.agent.robot.get_drive_targets().clone()
        return state

    def set_state(self, state: dict) -> None:
        """Restore a ``get_state()`` dict (batched to ``num_envs``)."""
        state = dict(state)
        targets = state.pop(DRIVE_KEY, None)
        self.env.set_state_dict(state)
        if "controller" in state and not isinstance(self.env, InsertionEnv):
            self.env.agent.set_controller_state(state["controller"])
        if targets is not None:
            robot = self.env.agent.robot
            robot.set_joint_drive_targets(torch.as_tensor(targets, device=self.env.device), robot.active_joints)

    def unflatten(self, flat) -> dict:
        """A flat state ``[B, D]`` (from ``flatten``) back to a dict shaped like ``get_state()``."""
        flat = torch.as_tensor(flat)
        return unflatten_like(self.get_state(), flat[None] if flat.ndim == 1 else flat)

    @staticmethod
    def flatten(state: dict) -> torch.Tensor:
        """Flat ``[B, D]`` form of a state dict, in ManiSkill's key order."""
        return flatten_state(state)


# The keys of a state dict that belong to the robot (its joints, drives, controller and our tasks' wrist F/T).
ROBOT_KEYS = ("controller", "task", DRIVE_KEY)


def compose_scene(robot_from: dict, rest_from: dict, robot: str) -> dict:
    """A state dict with the robot ``robot`` (and its controller, drives and F/T) of ``robot_from`` and every other
    body of ``rest_from``."""
    out = {k: v for k, v in rest_from.items() if k not in ROBOT_KEYS}
    out["articulations"] = {**rest_from.get("articulations", {}), robot: robot_from["articulations"][robot]}
    out.update({k: robot_from[k] for k in ROBOT_KEYS if k in robot_from})
    return out


def adapter_for(env) -> EnvAdapter:
    """The adapter of a ManiSkill env (wrapped or not)."""
    u = env.unwrapped
    if isinstance(u, InsertionEnv):
        return EnvAdapter(u, camera_map_for(u), has_ft=True, start_fn=lambda e: e.in_start_region())
    return EnvAdapter(u, camera_map_for(u), has_ft=hasattr(u, "ft"), gripper_idx=_gripper_joint_indices(u))
