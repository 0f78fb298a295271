"""A wrist 6-axis force/torque sensor with a short history, sampled at physics rate.

The reading is the wrench that the arm's last link exerts on the hand through the hand's
mounting joint (SAPIEN's ``get_link_incoming_joint_forces`` for the hand link), expressed in
that joint's frame, which is the hand frame: ``[fx, fy, fz, tx, ty, tz]`` in N and N m, with z
along the gripper's approach axis. Everything the hand holds (fingers and part) is beyond
the joint, so contact on the part shows up here as on a real wrist sensor. Robot links have
gravity off in ManiSkill and the held part is made weightless too, so free space reads ~0.

The sensor keeps the last ``history`` readings of every env in one ``[num_envs, history, 6]``
tensor; the newest reading is last.
"""

from __future__ import annotations

import torch

from mani_skill.utils.structs import Articulation


class WristFTSensor:
    """Batched wrist F/T sensor; call ``update()`` after every physics substep."""

    def __init__(self, robot: Articulation, link_name: str, history: int, device: torch.device):
        if history < 1:
            raise ValueError(f"F/T history length must be >= 1, got {history}")
        self.robot = robot
        names = [link.name for link in robot.get_links()]
        if link_name not in names:
            raise ValueError(f"F/T sensor link {link_name!r} is not a link of {robot.name}; links: {names}")
        self.link_index = names.index(link_name)
        self.history = history
        self.buffer = torch.zeros((len(robot._objs), history, 6), device=device)

    def read(self) -> torch.Tensor:
        """The current wrench ``[num_envs, 6]``."""
        return self.robot.get_link_incoming_joint_forces()[:, self.link_index].to(self.buffer.device)

    def update(self) -> None:
        """Append the current reading to the history (drops the oldest)."""
        self.buffer = torch.cat([self.buffer[:, 1:], self.read()[:, None]], dim=1)

    def reset(self, env_idx: torch.Tensor) -> None:
        """Clear the history of the given envs."""
        self.buffer[env_idx] = 0.0

    def get_state(self) -> torch.Tensor:
        """History flattened to ``[num_envs, history * 6]`` (ManiSkill states are at most 2-d)."""
        return self.buffer.reshape(self.buffer.shape[0], -1).clone()

    def set_state(self, state: torch.Tensor, env_idx: torch.Tensor | None = None) -> None:
        """Restore the history from ``get_state()`` output, for all envs or ``env_idx``."""
        state = torch.as_tensor(state, device=self.buffer.device, dtype=self.buffer.dtype)
        if state.ndim == 1:  # an unbatched state, as ManiSkill's trajectory replay passes
            state = state[None]
        state = state.reshape(state.shape[0], self.history, 6)
        if env_idx is None:
            self.buffer = state.clone()
        else:
            self.buffer[env_idx] = state[env_idx] if state.shape[0] == self.buffer.shape[0] else state
