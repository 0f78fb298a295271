"""Where the socket of an insertion task stands: its placement (x, y, yaw on the floor), drawn, read and moved.

``SocketPlacement`` is a mixin of ``InsertionEnv``: the backward sampler moves the socket of a restored state to
where any reset may put it (``place_socket``), so the encoder sees every placement from one demo.
"""

from __future__ import annotations

import numpy as np
import torch

from mani_skill.utils.geometry.rotation_conversions import axis_angle_to_quaternion
from mani_skill.utils.structs import Pose


def yaw_quat(yaw: torch.Tensor) -> torch.Tensor:
    """Quaternions ``[B, 4]`` (wxyz) of rotations by ``yaw`` about world z."""
    axis = torch.zeros(yaw.shape[0], 3, device=yaw.device)
    axis[:, 2] = yaw
    return axis_angle_to_quaternion(axis)


class SocketPlacement:
    """The socket's placement on the floor: read, drawn as resets draw it (the task's ``socket_center``,
    ``socket_xy_range``, ``socket_yaw_range``), and moved with the robot."""

    def socket_placements(self) -> torch.Tensor:
        """The socket's placement ``[num_envs, 3]``: x, y (m, world) and yaw (rad), as resets draw it."""
        pose = self.socket.pose
        q = pose.q  # yaw only: wxyz = (cos yaw/2, 0, 0, sin yaw/2)
        yaw = 2 * torch.atan2(q[:, 3], q[:, 0])
        return torch.cat([pose.p[:, :2], yaw[:, None]], dim=1)

    def random_socket_placements(self, rng: np.random.Generator, count: int) -> np.ndarray:
        """``count`` placements ``[count, 3]`` drawn as ``_initialize_episode`` draws the socket's."""
        xy = rng.uniform(-self.socket_xy_range, self.socket_xy_range, size=(count, 2)) + np.asarray(self.socket_center)
        yaw = rng.uniform(-self.socket_yaw_range, self.socket_yaw_range, size=(count, 1))
        return np.concatenate([xy, yaw], axis=1)

    @staticmethod
    def _socket_pose_at(xy: torch.Tensor, yaw: torch.Tensor, z: torch.Tensor) -> Pose:
        """The socket's pose ``[B]``: at ``xy`` ``[B, 2]`` on the floor, turned by ``yaw``, its base at ``z``."""
        return Pose.create_from_pq(torch.cat([xy, z[:, None]], dim=1), yaw_quat(yaw))

    def place_socket(self, placements) -> None:
        """Move the socket to ``placements`` ``[num_envs, 3]`` and the robot (with the held part) rigidly with it.

        Everything relative to the socket stays as it was, so the next step replays the same in
        the socket's frame (the robot's base moves instead of its joints: the floor and gravity do
        not care). The backward sampler uses this to show the encoder the socket where every
        reset may put it, from one demo.
        """
        placements = torch.as_tensor(placements, dtype=torch.float32, device=self.device).reshape(self.num_envs, 3)
        old = self.socket.pose
        new = self._socket_pose_at(placements[:, :2], placements[:, 2], old.p[:, 2])
        move = new * old.inv()
        root = self.agent.robot.pose
        self.socket.set_pose(new)
        self.agent.robot.set_root_pose(move * root)

    def pose_at_placement(self, raw_pose: torch.Tensor, placement) -> torch.Tensor:
        """World poses ``[B, 7]`` moved to where they would be with the socket at ``placement`` ``[3]`` (x, y, yaw)."""
        ref = torch.as_tensor(placement, dtype=torch.float32, device=self.device).reshape(1, 3).expand(self.num_envs, 3)
        socket = self.socket.pose
        move = self._socket_pose_at(ref[:, :2], ref[:, 2], socket.p[:, 2]) * socket.inv()
        return (move * Pose.create(raw_pose)).raw_pose
