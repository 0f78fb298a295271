"""The base of the stock scripted experts (``experts.stock``): pose helpers, the TCP servo, the shared grasp phases."""

from __future__ import annotations

import torch

from mani_skill.utils.geometry.rotation_conversions import (
    matrix_to_quaternion,
    quaternion_invert,
    quaternion_multiply,
    quaternion_to_axis_angle,
)
from mani_skill.utils.structs import Pose

from drem_maniskill.experts.control import require_ee_control

POS_SCALE = 0.1  # m per unit action (pos_lower/upper of the stock pd_ee_delta_pose)
ROT_SCALE = -0.1  # rad per unit action: rot_lower, negative in ManiSkill 3.0.1
GRIPPER_OPEN, GRIPPER_CLOSED = 1.0, -1.0


# ----------------------------------------------------------------------------- pose helpers
def _pose(p: torch.Tensor, q: torch.Tensor | None = None) -> Pose:
    """A batched Pose from positions ``[B, 3]`` and optional wxyz quaternions ``[B, 4]``."""
    if q is None:
        q = torch.zeros(p.shape[0], 4, device=p.device, dtype=p.dtype)
        q[:, 0] = 1
    return Pose.create_from_pq(p, q)


def _rot_error(q_target: torch.Tensor, q_current: torch.Tensor) -> torch.Tensor:
    """Rotation vector ``[B, 3]`` (world axes) turning ``q_current`` into ``q_target``."""
    q = quaternion_multiply(q_target, quaternion_invert(q_current))
    # Shortest way round: q and -q are the same rotation.
    q = torch.where(q[:, :1] < 0, -q, q)
    return quaternion_to_axis_angle(q)


NOISY_EXPERT_SIGMA = 0.1
"""The noisy expert's action noise unless an expert sets its own ``noisy_sigma``."""


# ----------------------------------------------------------------------------- experts
class _StockExpert:
    """Base: batched per-env phase and phase clock, reset at each env's first step, TCP servo."""

    env_id: str = ""
    ki = 0.3  # integral gain per step of the fine phases
    fine_from = 5  # first phase with integral action
    i_zone = float("inf")  # m; the integral only accumulates while the position error is below this
    noisy_sigma = NOISY_EXPERT_SIGMA  # the noisy_expert's N(0, sigma) on the normalised arm actions

    def __init__(self, env, seed: int = 0, action_noise: float = 0.0):
        self.env = env.unwrapped
        require_ee_control(env, "stock experts")
        self.device = self.env.device
        self.n = self.env.num_envs
        # Deterministic unless action_noise > 0; the seed fixes that noise.
        self.action_noise = float(action_noise)
        self.generator = torch.Generator(device="cpu").manual_seed(int(seed))
        self.phase = torch.zeros(self.n, dtype=torch.long, device=self.device)
        self.clock = torch.zeros(self.n, dtype=torch.long, device=self.device)
        self._grasp_raw = torch.zeros(self.n, 7, device=self.device)
        # Integral of the pose error (world axes), for the fine phases: the held part's weight
        # leaves a steady offset of a few mm under the arm's PD that the proportional servo
        # never removes.
        self._i_pos = torch.zeros(self.n, 3, device=self.device)
        self._i_rot = torch.zeros(self.n, 3, device=self.device)

    def __call__(self, obs=None) -> torch.Tensor:
        """Action ``[num_envs, 7]`` for the current state (``obs`` is not needed: state is privileged)."""
        fresh = self.env.elapsed_steps.to(self.device) == 0
        self.phase[fresh] = 0
        self.clock[fresh] = 0
        old = self.phase.clone()
        self._start = old  # transitions test the phase the step began in: one phase per step
        action = self.act()
        # Count steps spent in the current phase (timeouts, gripper closing time).
        same = self.phase == old
        self.clock = torch.where(same, self.clock + 1, torch.zeros_like(self.clock))
        # The integrals carry over between fine phases: resetting them would drop the part by
        # its sag just as it enters the hole.
        restart = (~same & (self.phase <= self.fine_from)) | fresh
        self._i_pos[restart] = 0
        self._i_rot[restart] = 0
        if self.action_noise > 0:
            noise = torch.randn(self.n, 6, generator=self.generator).to(self.device) * self.action_noise
            action[:, :6] = (action[:, :6] + noise).clamp(-1, 1)
        return action

    def act(self) -> torch.Tensor:
        raise NotImplementedError

    def servo(self, target: Pose, gripper: torch.Tensor, speed: float = 1.0,
              integral: torch.Tensor | None = None) -> torch.Tensor:
        """Action moving the TCP towards ``target`` (world frame): the whole error per step, capped.

        The translation is scaled (not clipped per axis) so the TCP moves in a straight line.
        Where ``integral`` (bool ``[B]``) is set, the accumulated error is added (PI control).
        """
        tcp = self.env.agent.tcp.pose
        e_pos = target.p - tcp.p
        e_rot = _rot_error(target.q, tcp.q)
        if integral is not None:
            # Conditional integration: far from the target the error is travel, not sag, and
            # integrating it winds up an overshoot.
            m = (integral & (torch.linalg.norm(e_pos, dim=1) < self.i_zone))[:, None].float()
            self._i_pos = (self._i_pos + m * e_pos).clamp(-0.05, 0.05)
            self._i_rot = (self._i_rot + m * e_rot).clamp(-0.2, 0.2)
            e_pos = e_pos + self.ki * m * self._i_pos
            e_rot = e_rot + self.ki * m * self._i_rot
        v = e_pos / POS_SCALE
        v = v / (v.abs().amax(dim=1, keepdim=True) / speed).clamp(min=1.0)
        w = e_rot / ROT_SCALE
        w = w / w.norm(dim=1, keepdim=True).clamp(min=1.0)
        return torch.cat([v, w, gripper[:, None]], dim=1)

    def tcp_target_for(self, obj_pose: Pose, obj_target: Pose) -> Pose:
        """TCP pose that puts the held object at ``obj_target``, keeping the measured grasp."""
        grasp = obj_pose.inv() * self.env.agent.tcp.pose
        return obj_target * grasp

    def pose_error(self, a: Pose, b: Pose) -> tuple[torch.Tensor, torch.Tensor]:
        """Position error norm and rotation angle ``[B]`` between two poses."""
        return torch.linalg.norm(a.p - b.p, dim=1), _rot_error(a.q, b.q).norm(dim=1)

    def dispatch(self, targets: list) -> torch.Tensor:
        """Action ``[B, 7]``: each env servos to the target of its phase (PI in the fine phases).

        ``targets`` holds ``(phase, target, gripper)`` or ``(phase, target, gripper, speed)``.
        """
        action = torch.zeros(self.n, 7, device=self.device)
        fine = self.phase >= self.fine_from
        for ph, target, grip, *speed in targets:
            mask = self.phase == ph
            if mask.any():
                action[mask] = self.servo(target, grip, *speed, integral=mask & fine)[mask]
        return action

    def latched_grasp(self) -> Pose:
        """The grasp pose, tracked until the gripper starts closing, then frozen.

        Once the part is held it moves with the hand, so a grasp pose recomputed from it would
        run away from the lift target.
        """
        fresh = self.phase <= 1
        if fresh.any():
            self._grasp_raw[fresh] = self.grasp_pose().raw_pose[fresh]
        return Pose.create(self._grasp_raw.clone())

    def grippers(self) -> tuple[torch.Tensor, torch.Tensor]:
        """Open and closed gripper commands ``[B]``."""
        return (torch.full((self.n,), GRIPPER_OPEN, device=self.device),
                torch.full((self.n,), GRIPPER_CLOSED, device=self.device))

    def advance_grasp(self, above: Pose, grasp: Pose, above_rot_tol: float, grasp_pos_tol: float,
                      grasp_timeout: int) -> None:
        """The grasp phases every stock expert shares: 0 reach ``above`` the grasp, 1 descend to it, 2 close, 3 lift."""
        tcp = self.env.agent.tcp.pose
        pe, re = self.pose_error(above, tcp)
        self._advance((pe < 0.01) & (re < above_rot_tol), 0, 1)
        pe, re = self.pose_error(grasp, tcp)
        self._advance(((pe < grasp_pos_tol) & (re < 0.05)) | (self.clock > grasp_timeout), 1, 2)
        self._advance(self.clock >= self.close_steps, 2, 3)
        self._advance(tcp.p[:, 2] > grasp.p[:, 2] + self.lift * 0.6, 3, 4)

    def _advance(self, cond: torch.Tensor, frm: int, to: int) -> None:
        self.phase = torch.where((self._start == frm) & cond, torch.full_like(self.phase, to), self.phase)


def _top_down_grasp_q(closing: torch.Tensor) -> torch.Tensor:
    """wxyz ``[B, 4]`` of a TCP frame approaching straight down (z = -world z) closing along ``closing``.

    Same frame as ``Panda.build_grasp_pose``: columns (closing x approaching, closing, approaching).
    """
    approaching = torch.zeros_like(closing)
    approaching[:, 2] = -1
    ortho = torch.cross(closing, approaching, dim=1)
    rot = torch.stack([ortho, closing, approaching], dim=2)
    return matrix_to_quaternion(rot)
