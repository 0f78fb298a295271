"""The reward modes of the insertion tasks: one table from mode to method, and the methods.

``InsertionRewards`` is a mixin of ``InsertionEnv``, ahead of ``DREMRewardMode`` so that its ``get_reward`` answers
every mode through the table (``"drem"`` is ``DREMRewardMode``'s, which also loads the checkpoint).
"""

from __future__ import annotations

from typing import Any

import torch

from drem_maniskill.baselines.engineered import engineered_reward, pose_distance


class InsertionRewards:
    """``REWARD_FUNCTIONS`` (mode -> method computing a ``[num_envs]`` tensor) and the task's own reward methods."""

    # One place to add a reward mode: its name here and its method.
    REWARD_FUNCTIONS = {
        "sparse": "compute_sparse_reward",
        "dense": "compute_dense_reward",
        "normalized_dense": "compute_normalized_dense_reward",
        "none": "_zero_reward",
        "drem": "compute_drem_reward",
        "engineered": "compute_engineered_reward",
    }
    SUPPORTED_REWARD_MODES = tuple(REWARD_FUNCTIONS)

    def get_reward(self, obs: Any, action: torch.Tensor, info: dict):
        """The reward of ``reward_mode``, by its method in ``REWARD_FUNCTIONS``."""
        return getattr(self, self.REWARD_FUNCTIONS[self.reward_mode])(obs=obs, action=action, info=info)

    def _zero_reward(self, obs: Any, action: torch.Tensor, info: dict):
        return torch.zeros(self.num_envs, device=self.device)

    def compute_engineered_reward(self, obs: Any, action: torch.Tensor, info: dict):
        """The paper's hand-crafted ``-exp(kappa d)``, d the tip's pose distance to the fully-inserted pose."""
        # Goal in the socket frame: on the axis at the bottom of the hole, axes aligned.
        goal = torch.tensor([[0.0, 0.0, -self.hole_depth]], device=self.device)
        rot_error = torch.sqrt(info["tilt_error"] ** 2 + info["yaw_error"] ** 2)
        return engineered_reward(pose_distance(info["tip_in_socket"], goal, rot_error), self.engineered_kappa)

    def compute_sparse_reward(self, obs: Any, action: torch.Tensor, info: dict):
        """1 on success, else 0."""
        return info["success"].float()

    def compute_dense_reward(self, obs: Any, action: torch.Tensor, info: dict):
        """Staged: reach above the opening (1), align axis and yaw (1), insert (2), success (6)."""
        height = info["tip_in_socket"][:, 2]
        radial = info["radial_offset"]
        # Descending below the pre-insertion height is not penalised by the reach stage.
        reach_dist = torch.sqrt(radial**2 + (height - 0.01).clamp(min=0) ** 2)
        reward = 1 - torch.tanh(5 * reach_dist)
        align = 0.5 * (1 - torch.tanh(200 * radial)) + 0.25 * (1 - torch.tanh(5 * info["tilt_error"]))
        align = align + 0.25 * (1 - torch.tanh(5 * info["yaw_error"]))
        reward = reward + align
        reward = reward + 2 * info["is_aligned"].float() * info["depth_fraction"]
        reward[info["success"]] = 6.0
        return reward

    def compute_normalized_dense_reward(self, obs: Any, action: torch.Tensor, info: dict):
        """``dense`` scaled to [0, 1]."""
        return self.compute_dense_reward(obs=obs, action=action, info=info) / 6.0
