"""The paper's ``Engineered`` baseline: ``R = -exp(kappa * ||x - x_G||)``.

``x`` is the end-effector pose and ``x_G`` the target pose. In our tasks the part is a rigid
link of the hand, so we measure the pose of the part's tip (the part frame) and take as
target the fully-inserted pose: tip at the bottom of the hole (``hole_depth`` below the
socket's top face, on its axis) with the part's axes aligned with the socket's (yaw modulo
the part's symmetry; free for the round peg).

The pose distance is ``||p - p_G||_2 + ROT_WEIGHT * theta`` in metres, with ``theta`` the
rotation error in radians (``sqrt(tilt^2 + yaw^2)``, the env's own tilt and symmetry-reduced
yaw errors) and ``ROT_WEIGHT = 0.1`` m/rad: turning a part about 10 cm long by ``theta``
moves its far end by about ``0.1 * theta``, so a radian counts like 10 cm of offset.

What it rewards: ``-exp(kappa * d)`` is maximal, ``-1``, at the goal (``d = 0``) and grows
more negative, exponentially, with the distance, so every step is penalised and the penalty
is smallest at the inserted pose. It knows nothing of contact: it pulls the tip straight
towards the bottom of the hole, through the socket's walls if that were shorter.
"""

from __future__ import annotations

import torch

# Default kappa in 1/m: episodes start about 6-12 cm from the inserted pose (reward about
# -1.8 to -3.3); at the goal it is -1. Larger kappa: steeper far away, same -1 at the goal.
DEFAULT_KAPPA = 10.0
# Metres of position error one radian of rotation error counts as (the part's length scale).
ROT_WEIGHT = 0.1


def pose_distance(pos: torch.Tensor, goal_pos: torch.Tensor, rot_error: torch.Tensor,
                  rot_weight: float = ROT_WEIGHT) -> torch.Tensor:
    """``||pos - goal_pos||_2 + rot_weight * rot_error``, batched: ``[B, 3], [B or 1, 3], [B] -> [B]``."""
    return torch.linalg.norm(pos - goal_pos, dim=-1) + rot_weight * rot_error


def engineered_reward(distance: torch.Tensor, kappa: float = DEFAULT_KAPPA) -> torch.Tensor:
    """The paper's hand-crafted reward ``-exp(kappa * distance)``: -1 at the goal, lower farther away."""
    return -torch.exp(kappa * distance)
