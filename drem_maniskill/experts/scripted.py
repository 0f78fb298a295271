"""Scripted policies for our insertion tasks: the expert and the paper's examination policies.

``drem_maniskill.experts.get_policy(name, env, seed=0)`` returns a callable ``policy(obs) -> action`` giving a
``[num_envs, action_dim]`` tensor for the ``pd_ee_delta_pose`` control mode. The policies read
privileged state (part and socket poses) and the wrist F/T history from ``env.unwrapped``;
each keeps a batched phase per env and starts over when that env's ``elapsed_steps`` is 0.

Names (Section IV-C of the paper):

* ``expert``: centre the tip above the opening, fix the yaw, insert.
* ``direct_success``: the expert's motion, as "imitate the expert" in the paper.
* ``align_success``: approach with a small translation error until contact, slide to the
  centre while pressing, insert.
* ``search_fail``: approach with a small error until contact, slide away from the centre while
  pressing until the part slides off the socket and contact is lost, then keep going.
* ``random``: uniform random actions.
"""

from __future__ import annotations

from typing import Optional

import numpy as np
import torch

from mani_skill.utils.geometry.rotation_conversions import quaternion_to_axis_angle, quaternion_to_matrix

from drem_maniskill.envs.agent import EE_POS_LIMIT, EE_ROT_LIMIT
from drem_maniskill.experts.control import require_ee_control

# Contact is declared when the wrist feels this much force along the approach axis.
CONTACT_FORCE = 3.0
PRESS_DEPTH = 0.002  # commanded below the surface when pressing: a few newtons through the arm's PD
DESCEND_FROM_TOLERANCE = 0.001  # m: the arm's PD stops a little short of the pre-insertion point


def _yaw_error(env) -> torch.Tensor:
    """Signed yaw of the part relative to the socket, wrapped to the part's symmetry."""
    rel = env.tip_pose_in_socket()
    rot = quaternion_to_matrix(rel.q)
    yaw = torch.atan2(rot[:, 1, 0], rot[:, 0, 0])
    if not env.yaw_symmetry:
        return torch.zeros_like(yaw)
    period = 2 * np.pi / env.yaw_symmetry
    return torch.remainder(yaw + period / 2, period) - period / 2


def _rotation_error(env, turn: Optional[torch.Tensor] = None) -> torch.Tensor:
    """Rotation vector ``[B, 3]`` (world axes) from the socket's orientation, or ``turn`` ``[B, 3]`` (socket frame)
    from it, to the part's.

    Tilt comes from the full relative rotation; yaw is taken modulo the part's symmetry (and
    ignored for a round part), so the policies never turn a part a needless half turn.
    """
    rel = env.tip_pose_in_socket()
    err = quaternion_to_axis_angle(rel.q)
    err[:, 2] = _yaw_error(env)
    if turn is not None:
        err = err - turn
    return _socket_to_world(env, err)


def _socket_to_world(env, vec: torch.Tensor) -> torch.Tensor:
    """Rotate ``[B, 3]`` vectors from the socket frame to the world frame."""
    rot = quaternion_to_matrix(env.opening_pose().q)
    return torch.einsum("bij,bj->bi", rot, vec)


class ScriptedPolicy:
    """Base: batched per-env phase, reset at each env's first step, action assembly."""

    def __init__(self, env, seed: int = 0):
        self.env = env.unwrapped
        require_ee_control(env)
        self.device = self.env.device
        self.n = self.env.num_envs
        self.generator = torch.Generator(device="cpu").manual_seed(int(seed))
        self.phase = torch.zeros(self.n, dtype=torch.long, device=self.device)

    def _rand(self, *shape) -> torch.Tensor:
        return torch.rand(*shape, generator=self.generator).to(self.device)

    def _on_reset(self, mask: torch.Tensor) -> None:
        self.phase[mask] = 0

    def __call__(self, obs) -> torch.Tensor:
        fresh = self.env.elapsed_steps.to(self.device) == 0
        if fresh.any():
            self._on_reset(fresh)
        return self.act()

    def act(self) -> torch.Tensor:
        raise NotImplementedError

    # -- helpers shared by the scripted motions
    def state(self):
        rel = self.env.tip_pose_in_socket()
        ft = self.env.ft.buffer[:, -1]
        # Approach-axis force in the hand frame (z points down the gripper).
        return rel.p, _yaw_error(self.env), ft[:, 2].abs()

    def move(self, target_in_socket: torch.Tensor, speed=1.0, turn: Optional[torch.Tensor] = None) -> torch.Tensor:
        """Action moving the tip towards ``target_in_socket`` ``[B, 3]`` (socket frame), upright, or turned by ``turn``.

        The default controller moves relative to the *current* pose, so contact torques would
        tilt the part a little more at every step; the rotation part undoes any tilt and yaw.
        ``turn`` ``[B, 3]`` (rotation vector, socket frame, as ``_rotation_error`` measures it) is the orientation
        error to hold instead of none. ``speed`` (a fraction of the action range, a float or ``[B]``) caps each
        component of the move along the world's axes leaned with the opening's (``axis_lean``), so a move along a
        tilted socket's axis stays on it.
        """
        tip = self.env.tip_pose_in_socket().p
        delta = target_in_socket - tip
        lean = self.env.axis_lean()
        delta_lean = torch.einsum("bji,bj->bi", lean, _socket_to_world(self.env, delta))
        speed = torch.as_tensor(speed, dtype=delta.dtype, device=self.device).expand(self.n)[:, None]
        step = torch.minimum(torch.maximum(delta_lean / EE_POS_LIMIT, -speed), speed)
        action = torch.zeros(self.n, 6, device=self.device)
        action[:, :3] = torch.einsum("bij,bj->bi", lean, step)
        # pd_ee_delta_pose rotates about root-aligned axes at the TCP, by the action times
        # ``rot_lower`` (= -EE_ROT_LIMIT in ManiSkill 3.0): +error undoes the error.
        action[:, 3:] = (_rotation_error(self.env, turn) / EE_ROT_LIMIT).clamp(-1, 1)
        return action


class ExpertPolicy(ScriptedPolicy):
    """Centre above the opening, correct yaw, then descend along the axis to the bottom.

    It slows down near the opening, as a careful demonstrator does: the last centimetre of the
    approach at ``fine_speed`` and the first ``fine_depth`` of the insertion ``fine_step`` at a
    time (or ``descent_step``, where that is smaller). The backward sampler walks the demo back
    step by step, so these slow steps are what give the progress tree depths that tell hovering
    above the opening, touching its rim and being in it apart (docs/experiment-log.md, "A slower expert near the
    opening, and actions that follow the expert's step").
    """

    pre_height = 0.006
    centred = 0.0006
    descent_step = 0.005  # m the tip is sent down per step once aligned and past fine_depth
    fine_step = 0.002  # m per step while entering the opening
    fine_depth = 0.006  # m below the top face the entry ends
    fine_radius = 0.01  # m from the pre-insertion point the approach slows to fine_speed
    fine_speed = 0.15  # of the action range: 3 mm per step

    descend_from = None  # m above the top face the aligned descent starts; None: wherever the tip aligned

    def __init__(self, env, seed: int = 0, descent_step: Optional[float] = None, descend_from: Optional[float] = None):
        super().__init__(env, seed)
        if descent_step is not None:
            # A slower descent gives the tree more depths inside the hole (record-expert --descent-step).
            if not 0 < descent_step <= 0.02:
                raise ValueError("descent_step is metres per step in (0, 0.02] (the controller's range), "
                                 f"got {descent_step}")
            self.descent_step = float(descent_step)
        if descend_from is not None:
            # The expert usually aligns 2-3 cm above the opening and then crawls down at the entry step from there,
            # spending half the demo hovering; from descend_from it approaches the pre-insertion point as it
            # approached the axis (record-expert --descend-from; docs/experiment-log.md, "A shorter approach above
            # the port").
            if not 0 < descend_from <= 0.05:
                raise ValueError(f"descend_from is metres above the socket's top face in (0, 0.05], got {descend_from}")
            self.descend_from = float(descend_from)

    def act(self) -> torch.Tensor:
        tip, yaw, _ = self.state()
        radial = tip[:, :2].norm(dim=1)
        aligned = (radial < self.centred) & (yaw.abs() < np.deg2rad(2))
        if self.descend_from is not None:
            aligned = aligned & (tip[:, 2] < self.descend_from + DESCEND_FROM_TOLERANCE)
        # Once aligned above the hole (or already inside it), go down; never back up.
        self.phase = torch.where(aligned | (tip[:, 2] < 0), torch.ones_like(self.phase), self.phase)
        target = torch.zeros_like(tip)
        # The entry is never faster than the descent: a descent_step below fine_step slows the whole insertion.
        step = torch.where(tip[:, 2] > -self.fine_depth,
                           torch.full_like(tip[:, 2], min(self.fine_step, self.descent_step)),
                           torch.full_like(tip[:, 2], self.descent_step))
        # A descend_from below the pre-insertion point is approached instead, or the expert would stop short of it.
        approach = self.pre_height if self.descend_from is None else min(self.pre_height, self.descend_from)
        target[:, 2] = torch.where(self.phase == 1, tip[:, 2] - step, torch.full_like(tip[:, 2], approach))
        # The last centimetre of the approach at fine_speed.
        slow = (self.phase == 0) & ((tip - target).norm(dim=1) < self.fine_radius)
        return self.move(target, speed=torch.where(slow, self.fine_speed, 0.5))


class AlignSuccessPolicy(ScriptedPolicy):
    """Approach off-centre until contact, slide to the centre while pressing, insert."""

    error_range = (0.002, 0.004)

    def _on_reset(self, mask):
        super()._on_reset(mask)
        if not hasattr(self, "offset"):
            self.offset = torch.zeros(self.n, 2, device=self.device)
        angle = self._rand(self.n) * 2 * np.pi
        radius = self.error_range[0] + self._rand(self.n) * (self.error_range[1] - self.error_range[0])
        new = torch.stack([torch.cos(angle), torch.sin(angle)], dim=1) * radius[:, None]
        self.offset[mask] = new[mask]

    def act(self) -> torch.Tensor:
        tip, yaw, force = self.state()
        radial = tip[:, :2].norm(dim=1)
        contact = force > CONTACT_FORCE
        # 0 approach with the error, 1 slide to the centre pressing, 2 insert.
        self.phase = torch.where((self.phase == 0) & (contact | (tip[:, 2] < 0.0005)), 1, self.phase)
        self.phase = torch.where((self.phase == 1) & ((radial < 0.0006) | (tip[:, 2] < -0.002)), 2, self.phase)
        target = torch.zeros_like(tip)
        approach = self.phase == 0
        target[approach, :2] = self.offset[approach]
        target[approach, 2] = -PRESS_DEPTH
        slide = self.phase == 1
        target[slide, :2] = tip[slide, :2] - 0.006 * tip[slide, :2] / radial[slide, None].clamp(min=1e-6)
        target[slide, 2] = -PRESS_DEPTH
        insert = self.phase == 2
        target[insert, 2] = tip[insert, 2] - 0.01
        return self.move(target, speed=0.5)


class SearchFailPolicy(AlignSuccessPolicy):
    """Approach off-centre until contact, slide away from the centre until contact is lost."""

    def act(self) -> torch.Tensor:
        tip, yaw, force = self.state()
        radial = tip[:, :2].norm(dim=1).clamp(min=1e-6)
        contact = force > CONTACT_FORCE
        # 0 approach, 1 slide away pressing, 2 lost contact: keep drifting outwards and down.
        self.phase = torch.where((self.phase == 0) & (contact | (tip[:, 2] < 0.0005)), 1, self.phase)
        self.phase = torch.where((self.phase == 1) & (tip[:, 2] < -0.003), 2, self.phase)
        direction = tip[:, :2] / radial[:, None]
        target = torch.zeros_like(tip)
        approach = self.phase == 0
        target[approach, :2] = self.offset[approach]
        target[approach, 2] = -PRESS_DEPTH
        away = ~approach
        target[away, :2] = tip[away, :2] + 0.006 * direction[away]
        target[away, 2] = torch.where(self.phase[away] == 1, -PRESS_DEPTH, tip[away, 2] - 0.004)
        return self.move(target, speed=0.5)


class HoldPolicy(ScriptedPolicy):
    """Move the tip to ``target`` (socket frame, ``[3]`` or ``[B, 3]``) and hold it there, upright (or ``turn``ed).

    Not an examination policy of the paper: the reward examination uses it to read the reward
    with the tip held at the same places in every episode (colour spread, alignment, contact).
    A target below the socket's top face off the opening presses the part on the face.
    """

    VIA_REACHED = 0.001  # m from ``via`` at which the policy turns to ``target``

    def __init__(self, env, target, seed: int = 0, speed: float = 0.5, via=None, turn=None):
        super().__init__(env, seed)
        self.target = torch.as_tensor(target, dtype=torch.float32, device=self.device).expand(self.n, 3).clone()
        self.speed = speed
        # ``turn``: the rotation vector (socket frame, rad; x, y tilt, z turns about the part's axis) to hold the part
        # at instead of upright, as a policy hovering with the part turned away from the port does (a round part has
        # no turn about its axis: ``_rotation_error`` ignores it, and so does this).
        self.turn = None
        if turn is not None:
            vec = [float(a) for a in turn]
            vec[2] = vec[2] if self.env.yaw_symmetry else 0.0
            self.turn = torch.tensor(vec, dtype=torch.float32, device=self.device).expand(self.n, 3)
        # A straight line from the start to a target beside the socket's block, below its top face,
        # would catch the part on the block's edge: the ``via`` points (socket frame, ``[3]`` or ``[K, 3]``)
        # are passed through first, in order.
        if via is None:
            self.waypoints = self.target[None]
        else:
            via = torch.as_tensor(via, dtype=torch.float32, device=self.device).reshape(-1, 3)
            self.waypoints = torch.cat([via[:, None].expand(-1, self.n, 3), self.target[None]])

    def act(self) -> torch.Tensor:
        # phase k: on the way to waypoint k (reset to 0 per env by ScriptedPolicy); the last is the target.
        tip = self.env.tip_pose_in_socket().p
        rows = torch.arange(self.n, device=self.device)
        last = len(self.waypoints) - 1
        reached = (tip - self.waypoints[self.phase, rows]).norm(dim=1) < self.VIA_REACHED
        self.phase = torch.where(reached & (self.phase < last), self.phase + 1, self.phase)
        return self.move(self.waypoints[self.phase, rows], speed=self.speed, turn=self.turn)


class RandomPolicy(ScriptedPolicy):
    """Uniform random actions in the action space (seeded)."""

    def act(self) -> torch.Tensor:
        return self._rand(self.n, 6) * 2 - 1



# Name -> policy class, for our insertion tasks (the paper's Section IV-C).
POLICIES: dict[str, type[ScriptedPolicy]] = {
    "expert": ExpertPolicy,
    "direct_success": ExpertPolicy,
    "align_success": AlignSuccessPolicy,
    "search_fail": SearchFailPolicy,
    "random": RandomPolicy,
}
POLICY_NAMES = tuple(POLICIES)
