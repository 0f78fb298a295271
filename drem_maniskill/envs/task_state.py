"""What an insertion task observes and saves beyond ManiSkill's own: the wrist F/T history and the drive targets.

``TaskState`` is a mixin of ``InsertionEnv``. The F/T sensor (``envs.ft_sensor``) is read after every physics
substep; its history is an observation and part of the state, as are the joints' drive targets, so that a restored
state's next step replays the one it was saved before.
"""

from __future__ import annotations

import torch

from drem_maniskill.utils.state import unflatten_like


class TaskState:
    """Observation extras, and ``get_state_dict`` / ``set_state_dict`` / ``set_state`` with the task's own keys."""

    def _after_simulation_step(self):
        self.ft.update()

    def _get_obs_extra(self, info: dict):
        obs = dict(tcp_pose=self.agent.tcp.pose.raw_pose, ft=self.ft.buffer.clone())
        if self.obs_mode_struct.use_state:
            obs.update(
                part_pose=self.part.pose.raw_pose,
                socket_pose=self.socket.pose.raw_pose,
                tip_in_socket=info["tip_in_socket"],
            )
        return obs

    def get_state_dict(self):
        """Sim state plus controller state, the F/T history and drive targets (to replay a step)."""
        state = super().get_state_dict()
        state["task"] = dict(
            ft_history=self.ft.get_state(),
            drive_targets=self.agent.robot.get_drive_targets().clone(),
        )
        return state

    def set_state_dict(self, state: dict, env_idx: torch.Tensor = None):
        """Restore a ``get_state_dict()`` state, including the controller and the F/T history."""
        super().set_state_dict(state, env_idx)
        if "controller" in state:
            self.agent.set_controller_state(state["controller"])
        task = state.get("task", {})
        if "ft_history" in task:
            self.ft.set_state(task["ft_history"], env_idx)
        if "drive_targets" in task:
            targets = torch.as_tensor(task["drive_targets"], device=self.device)
            if targets.ndim == 1:
                targets = targets[None].expand(self.num_envs, -1)
            if env_idx is not None:
                current = self.agent.robot.get_drive_targets().clone()
                current[env_idx] = targets[env_idx]
                targets = current
            self.agent.robot.set_joint_drive_targets(targets, self.agent.robot.active_joints)

    def set_state(self, state, env_idx: torch.Tensor = None):
        """Restore a flat ``get_state()`` vector, task keys included (ManiSkill's drops them)."""
        template = self.get_state_dict()
        state = torch.as_tensor(state, device=self.device)
        if state.ndim == 1:
            state = state[None]
        self.set_state_dict(unflatten_like(template, state), env_idx)
