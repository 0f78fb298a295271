"""Scripted experts for ManiSkill's PegInsertionSide-v1, PlugCharger-v1, PushCube-v1, StackCube-v1 (no planner).

The experts follow the phases of ManiSkill's motion-planning solutions
(``mani_skill/examples/motionplanning/panda/solutions/``): reach above the grasp pose, descend,
close the gripper, lift, move to a pre-insertion pose aligned with the hole / receptacle, insert
along its axis. Instead of planning joint paths they servo the TCP towards each phase's target
pose with ``control_mode="pd_ee_delta_pose"``, reading privileged state from ``env.unwrapped``.

Controller facts this relies on (stock ``panda`` / ``panda_wristcam``, ManiSkill 3.0.1, checked
empirically at 20 Hz control / 100 Hz physics):

* action ``[dx, dy, dz, rx, ry, rz, gripper]`` in ``[-1, 1]``; translation in the robot root
  frame (world axes here: the root is only translated), scaled by 0.1 m;
* rotation about the TCP, root-aligned, scaled by ``rot_lower = -0.1`` rad, i.e. **+1 turns by
  -0.1 rad** (``PDEEPoseController._clip_and_scale_action``); the rotation part is clipped by norm;
* targets are relative to the *current* TCP pose and the joint PD lags, so a full-scale command
  moves only ~1.4 cm (or ~0.04 rad) per step; commanding the whole error each step (gain 1)
  converges without overshoot to ~0.1 mm, larger gains oscillate;
* gripper: +1 open (0.04 m per finger), -1 closed (target -0.01 m, squeezes what it holds).

Targets are recomputed every step from the measured poses (the part's target pose times the
measured part-to-TCP transform), so slip in the grasp is corrected on the way.

DREM's sampler does not use a start region from here: on a stock task it is the demo's first
TCP position (``drem_maniskill.envs.adapter``), so any demo works the same way.
"""

from __future__ import annotations

import numpy as np
import torch

from mani_skill.utils.geometry.rotation_conversions import axis_angle_to_quaternion, quaternion_multiply
from mani_skill.utils.structs import Pose

from drem_maniskill.experts.stock_base import (
    _pose,
    _StockExpert,
    _top_down_grasp_q,
)
from drem_maniskill.experts.stock_tabletop import PushCubeExpert, StackCubeExpert


class PegInsertionSideExpert(_StockExpert):
    """Grasp the peg near its tail from above, carry it in front of the hole, push it in sideways.

    Phases: 0 reach 5 cm above the grasp, 1 descend, 2 close, 3 lift, 4 align the peg 5 cm
    before the entrance, 5 align it 1 cm before the entrance, 6 insert along the hole axis.
    """

    env_id = "PegInsertionSide-v1"
    lift = 0.05
    close_steps = 5
    insert_lead = 0.01  # m ahead of the peg per step while inserting: slow enough to stay centred

    def grasp_pose(self) -> Pose:
        """TCP grasp pose: top-down on the peg's axis, ``max(5 cm, L/2 + 1 cm)`` behind the centre."""
        u = self.env
        peg = u.peg.pose
        half = u.peg_half_sizes
        rot = peg.to_transformation_matrix()[:, :3, :3]
        axis, side = rot[:, :, 0], rot[:, :, 1]
        # Of the two closing directions, take the one closer to the hand's current y axis:
        # the smaller turn of the wrist (what compute_grasp_info_by_obb does with target_closing).
        tcp_y = self.env.agent.tcp.pose.to_transformation_matrix()[:, :3, 1]
        side = torch.where((side * tcp_y).sum(1, keepdim=True) < 0, -side, side)
        back = torch.clamp(half[:, 0] / 2 + 0.01, min=0.05)
        p = peg.p - axis * back[:, None]
        return _pose(p, _top_down_grasp_q(side))

    def act(self) -> torch.Tensor:
        u = self.env
        open_, closed = self.grippers()
        half = u.peg_half_sizes[:, 0]

        grasp = self.latched_grasp()
        above = _pose(grasp.p + torch.tensor([0, 0, 0.05], device=self.device), grasp.q)
        # The open fingers straddle the peg with room to spare, so the last of the wrist turn
        # can finish on the way down (the turn, not the travel, is what takes longest).
        self.advance_grasp(above, grasp, above_rot_tol=0.15, grasp_pos_tol=0.004, grasp_timeout=20)

        goal = u.goal_pose  # peg pose with its head at the hole centre
        peg = u.peg.pose
        far = goal * _pose(torch.stack([-half - 0.05, torch.zeros_like(half), torch.zeros_like(half)], 1))
        near = goal * _pose(torch.stack([-half - 0.01, torch.zeros_like(half), torch.zeros_like(half)], 1))
        pe, re = self.pose_error(far, peg)
        self._advance((pe < 0.01) & (re < 0.05), 4, 5)
        head_in_hole = (u.box_hole_pose.inv() * u.peg_head_pose).p
        peg_in_goal = (goal.inv() * peg).p
        lateral = torch.maximum(head_in_hole[:, 1:].abs().amax(1), peg_in_goal[:, 1:].abs().amax(1))
        pe, re = self.pose_error(near, peg)
        self._advance((pe < 0.003) & (lateral < 0.0015), 5, 6)

        # Insert: walk the peg along the hole axis, insert_lead ahead of where it is, stopping 1 cm past
        # the goal (success needs the head within 1.5 cm of the box centre); keep it centred.
        x = (peg_in_goal[:, 0] + self.insert_lead).clamp(max=0.01)
        inserted = goal * _pose(torch.stack([x, torch.zeros_like(x), torch.zeros_like(x)], 1))

        to_far = self.tcp_target_for(peg, far)
        targets = [
            (0, above, open_),
            (1, grasp, open_),
            (2, grasp, closed),
            # Lift straight up, already turning the peg (about the vertical) towards the hole.
            (3, _pose(grasp.p + torch.tensor([0, 0, self.lift], device=self.device), to_far.q), closed),
            (4, to_far, closed),
            (5, self.tcp_target_for(peg, near), closed),
            (6, self.tcp_target_for(peg, inserted), closed),
        ]
        return self.dispatch(targets)


class PlugChargerExpert(_StockExpert):
    """Grasp the charger base from above (tilted 15 deg back), align with the receptacle, push in.

    Phases: 0 reach 5 cm above the grasp, 1 descend, 2 close, 3 lift (turning), 4 align the
    charger 5 cm before the receptacle, 5 approach slowly to 2 mm between pin tips and receptacle
    face and centre the tips there, 6 insert 2 mm ahead per step along the receptacle axis; back
    to 5 if the pins stop on the face off the hole.
    """

    env_id = "PlugCharger-v1"
    lift = 0.05
    close_steps = 5
    grasp_tilt = np.deg2rad(15)
    lateral_tol = 0.0003  # m; the pins have 0.5 mm clearance a side
    insert_lead = 0.002  # m ahead of the charger per step while pushing in: slow enough to stay centred
    near_gap = 0.002  # m between the pin tips and the receptacle face when lining up
    near_speed = 0.05  # action units (5 mm per step) on the way to "near"
    i_zone = 0.005  # m: the 3 cm approach to "near" is travel, not sag (see servo)

    def grasp_pose(self) -> Pose:
        """TCP grasp pose: top-down on the base centre, closing across it, tilted away from the pins."""
        u = self.env
        base = u.charger_base_pose
        rot = base.to_transformation_matrix()[:, :3, :3]
        # closing = -y of the charger makes the TCP x axis (closing x approaching) the pins'
        # direction, so the positive tilt about TCP y leans the hand away from the receptacle.
        closing = -rot[:, :, 1]
        q = _top_down_grasp_q(closing)
        tilt = torch.zeros(self.n, 3, device=self.device)
        tilt[:, 1] = self.grasp_tilt
        q = quaternion_multiply(q, axis_angle_to_quaternion(tilt))
        return _pose(base.p, q)

    def act(self) -> torch.Tensor:
        u = self.env
        n = self.n
        open_, closed = self.grippers()

        grasp = self.latched_grasp()
        # 5 cm back along the approach direction, as in the motion-planning solution.
        approach = grasp.to_transformation_matrix()[:, :3, 2]
        above = _pose(grasp.p - 0.05 * approach, grasp.q)
        self.advance_grasp(above, grasp, above_rot_tol=0.05, grasp_pos_tol=0.003, grasp_timeout=15)

        goal = u.goal_pose
        charger = u.charger.pose
        zeros = torch.zeros(n, device=self.device)
        # The pins are 16 mm long and enter the receptacle at goal x = -16 mm: "far" holds them
        # 34 mm out, "near" near_gap out, where the lateral error is servoed below the clearance.
        far = goal * _pose(torch.stack([zeros - 0.05, zeros, zeros], 1))
        near = goal * _pose(torch.stack([zeros - 0.016 - self.near_gap, zeros, zeros], 1))
        pe, re = self.pose_error(far, charger)
        self._advance((pe < 0.005) & (re < 0.03), 4, 5)
        rel = (goal.inv() * charger).p
        # The pin tips are what must hit the hole: a yaw error moves them 16 mm x angle sideways.
        tips = (goal.inv() * charger * _pose(torch.stack([zeros + 0.016, zeros, zeros], 1))).p
        lateral = torch.maximum(rel[:, 1:].abs().amax(1), tips[:, 1:].abs().amax(1))
        pe, re = self.pose_error(near, charger)
        self._advance((pe < 0.001) & (lateral < self.lateral_tol) & (re < 0.01), 5, 6)
        # Pins stopped on the receptacle face off the hole: pressing on only tilts the charger in
        # the fingers, so back off to "near" and line up again.
        blocked = (rel[:, 0] < -0.0155) & (lateral > 0.001) & (self.clock > 3)
        self._advance(blocked, 6, 5)

        x = (rel[:, 0] + self.insert_lead).clamp(max=0.0)
        inserted = goal * _pose(torch.stack([x, zeros, zeros], 1))

        to_far = self.tcp_target_for(charger, far)
        # Lift straight up, already turning the charger towards the receptacle: the turn (up to
        # ~1.4 rad at ~0.04 rad per step), not the travel, is what takes longest.
        lifted = _pose(grasp.p + torch.tensor([0, 0, self.lift], device=self.device), to_far.q)
        targets = [
            (0, above, open_),
            (1, grasp, open_),
            (2, grasp, closed),
            (3, lifted, closed),
            (4, to_far, closed),
            # Capped speed (~2 mm of travel per step): at full speed the held charger swings past
            # "near" onto the receptacle face or off-centre and has to back off (8 of 50 seeds).
            (5, self.tcp_target_for(charger, near), closed, self.near_speed),
            (6, self.tcp_target_for(charger, inserted), closed),
        ]
        return self.dispatch(targets)


STOCK_EXPERTS: dict[str, type[_StockExpert]] = {
    "PegInsertionSide-v1": PegInsertionSideExpert,
    "PlugCharger-v1": PlugChargerExpert,
    "PushCube-v1": PushCubeExpert,
    "StackCube-v1": StackCubeExpert,
}


def _env_id(env) -> str:
    spec = getattr(env.unwrapped, "spec", None)
    return spec.id if spec is not None else type(env.unwrapped).__name__


def get_stock_expert(env, seed: int = 0, **kwargs) -> _StockExpert:
    """The scripted expert for a stock ManiSkill env, picked by its id; ValueError otherwise."""
    env_id = _env_id(env)
    if env_id not in STOCK_EXPERTS:
        raise ValueError(f"no stock scripted expert for {env_id!r}; supported: {sorted(STOCK_EXPERTS)}")
    return STOCK_EXPERTS[env_id](env, seed=seed, **kwargs)
