"""How the DREM pipeline reads an env: cameras, F/T, end-effector state, start region, states.

The sampler, the recorder and the reward only talk to an env through ``EnvAdapter``, so the
same pipeline runs on our insertion tasks and on any ManiSkill task (``PegInsertionSide-v1``,
``PlugCharger-v1``, a user's own). ``adapter_for(env)`` picks:

* **our tasks** (``InsertionEnv``): cameras ``fixed_camera`` / ``wrist_camera``, the wrist F/T
  history, the task's ``in_start_region()``, and states that already replay a step;
* **any other ManiSkill env**: the first non-wrist camera as ``fixed`` (``base_camera`` in
  ManiSkill's tabletop tasks) and ``hand_camera`` as ``wrist`` when the robot has one
  (``panda_wristcam``), images only (no F/T sensor), and as start region "the end-effector
  within ``radius`` of the expert's first pose, gripper opening within 2 cm of the expert's".

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

OUR_CAMERAS = {"fixed": "fixed_camera", "wrist": "wrist_camera"}
WRIST_CAMERA_UIDS = ("hand_camera", "wrist_camera")
DRIVE_KEY = "drem_drive_targets"


def _is_insertion_env(env) -> bool:
    from drem_maniskill.envs.insertion_base import InsertionEnv

    return isinstance(env, InsertionEnv)


def camera_map_for(env) -> dict:
    """Modality -> camera uid of ``env`` (``fixed`` always, ``wrist`` when it has a wrist camera)."""
    env = env.unwrapped
    if _is_insertion_env(env):
        return dict(OUR_CAMERAS)
    uids = [uid for uid, s in env._sensors.items() if hasattr(s, "camera")]
    if not uids:
        raise ValueError(
            f"{env.spec.id if env.spec else type(env).__name__} has no camera; DREM needs at least one RGB camera "
            "(pass sensor_configs or a robot with a camera)"
        )
    wrist = [u for u in uids if u in WRIST_CAMERA_UIDS]
    fixed = [u for u in uids if u not in WRIST_CAMERA_UIDS]
    out = {"fixed": fixed[0] if fixed else uids[0]}
    if wrist and wrist[0] != out["fixed"]:
        out["wrist"] = wrist[0]
    return out


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
        data = obs.get("sensor_data", {}) if isinstance(obs, dict) else {}
        if all("rgb" in data.get(uid, {}) for uid in self.camera_map.values()):
            return {m: data[uid]["rgb"] for m, uid in self.camera_map.items()}
        u = self.env
        u.scene.update_render(update_sensors=True, update_human_render_cameras=False)
        out = {}
        for m, uid in self.camera_map.items():
            u._sensors[uid].capture()
            out[m] = u._sensors[uid].get_obs(rgb=True, depth=False, position=False, segmentation=False)["rgb"]
        return out

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

    def get_state(self) -> dict:
        """A state dict that replays the next step when restored (drive targets included)."""
        state = self.env.get_state_dict()
        if not _is_insertion_env(self.env):
            state[DRIVE_KEY] = self.env.agent.robot.get_drive_targets().clone()
        return state

    def set_state(self, state: dict) -> None:
        """Restore a ``get_state()`` dict (batched to ``num_envs``)."""
        state = dict(state)
        targets = state.pop(DRIVE_KEY, None)
        self.env.set_state_dict(state)
        if "controller" in state and not _is_insertion_env(self.env):
            self.env.agent.set_controller_state(state["controller"])
        if targets is not None:
            robot = self.env.agent.robot
            robot.set_joint_drive_targets(torch.as_tensor(targets, device=self.env.device), robot.active_joints)

    def unflatten(self, flat) -> dict:
        """A flat state ``[B, D]`` (from ``flatten``) back to a dict shaped like ``get_state()``."""
        from drem_maniskill.envs.insertion_base import _unflatten_like

        flat = torch.as_tensor(flat)
        return _unflatten_like(self.get_state(), flat[None] if flat.ndim == 1 else flat)

    @staticmethod
    def flatten(state: dict) -> torch.Tensor:
        """Flat ``[B, D]`` form of a state dict, in ManiSkill's key order."""
        from mani_skill.utils import common

        return common.flatten_state_dict(state, use_torch=True)


def adapter_for(env) -> EnvAdapter:
    """The adapter of a ManiSkill env (wrapped or not)."""
    u = env.unwrapped
    if _is_insertion_env(u):
        return EnvAdapter(u, dict(OUR_CAMERAS), has_ft=True, start_fn=lambda e: e.in_start_region())
    return EnvAdapter(u, camera_map_for(u), has_ft=hasattr(u, "ft"), gripper_idx=_gripper_joint_indices(u))
