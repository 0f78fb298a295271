"""Scripted experts for ManiSkill's PushCube-v1 and StackCube-v1 (no motion planner).

They follow the phases of ManiSkill's motion-planning solutions
(``mani_skill/examples/motionplanning/panda/solutions/push_cube.py``, ``stack_cube.py``) and,
like the experts in ``experts.stock``, servo the TCP towards each phase's target pose with
``control_mode="pd_ee_delta_pose"``, reading privileged state from ``env.unwrapped``. Every
target is recomputed each step from the measured poses, so a cube that slides while pushed or
slips in the fingers is followed.

Neither task needs the integral action of the insertion experts: a 4 cm cube weighs too little
to make the arm sag, and the success tolerances are centimetres, not tenths of a millimetre.
"""

from __future__ import annotations

import torch

from mani_skill.utils.structs import Pose

from drem_maniskill.experts.stock_base import _pose, _StockExpert, _top_down_grasp_q

NO_INTEGRAL = 1_000  # a phase index no expert reaches: proportional servo only


def _best_top_down_q(candidates: torch.Tensor, score: torch.Tensor) -> torch.Tensor:
    """Top-down TCP quaternion ``[B, 4]`` closing along the highest-``score [B, K]`` of ``candidates [B, K, 3]``."""
    best = score.argmax(1)
    closing = candidates[torch.arange(candidates.shape[0], device=candidates.device), best]
    return _top_down_grasp_q(closing)


def _alignment(candidates: torch.Tensor, direction: torch.Tensor) -> torch.Tensor:
    """Dot products ``[B, K]`` of ``candidates [B, K, 3]`` with ``direction [B, 3]``."""
    return (candidates * direction[:, None]).sum(-1)


class PushCubeExpert(_StockExpert):
    """Close the gripper, drop behind the cube, push it along +x into the goal region.

    Phases: 0 go above a point ``behind`` the cube (clear of its top, whichever side the TCP
    starts on), 1 descend to the cube's centre height, 2 push it towards the goal, keeping the
    fingers centred on it.
    """

    env_id = "PushCube-v1"
    fine_from = NO_INTEGRAL
    behind = 0.05  # m from the cube centre to the TCP before pushing (as the motion-planning solution)
    hover = 0.07  # m TCP height while going behind the cube: the closed fingertips clear its 4 cm top
    push_speed = 0.5  # action units: hitting the cube at full speed kicks it off the fingers
    goal_offset = 0.05  # m short of the goal centre; success needs < goal_radius (0.1 m) in xy
    # 0.1 never fails here (20 of 20 seeds), 0.3 solves 11 of 20: the examination needs failures near the goal.
    noisy_sigma = 0.3

    def __init__(self, env, seed: int = 0, action_noise: float = 0.0):
        super().__init__(env, seed=seed, action_noise=action_noise)
        self._q_raw = torch.zeros(self.n, 4, device=self.device)

    def push_q(self) -> torch.Tensor:
        """TCP orientation ``[B, 4]``: top-down, fingers side by side across the push, latched at the first step.

        Latched so the wrist does not follow its own drift; closing along world y makes the closed
        fingers a front 2 fingers wide.
        """
        fresh = self.env.elapsed_steps.to(self.device) == 0
        if fresh.any():
            tcp_y = self.env.agent.tcp.pose.to_transformation_matrix()[:, :3, 1]
            y = torch.zeros_like(tcp_y)
            y[:, 1] = 1
            ys = torch.stack([y, -y], 1)
            self._q_raw[fresh] = _best_top_down_q(ys, _alignment(ys, tcp_y))[fresh]
        return self._q_raw.clone()

    def act(self) -> torch.Tensor:
        """Action ``[B, 7]`` for each env's phase."""
        u = self.env
        _, closed = self.grippers()
        q = self.push_q()
        cube = u.obj.pose.p
        half = u.cube_half_size
        tcp = u.agent.tcp.pose.p

        start = cube.clone()
        start[:, 0] -= self.behind
        above = start.clone()
        above[:, 2] = self.hover
        start[:, 2] = half
        self._advance(torch.linalg.norm(above - tcp, dim=1) < 0.01, 0, 1)
        self._advance(torch.linalg.norm(start - tcp, dim=1) < 0.005, 1, 2)

        # Move the TCP by what the cube still lacks: before contact this closes the gap, after it
        # the cube moves with the fingers; the cube's y is tracked so it stays centred on them.
        lack = (u.goal_region.pose.p[:, 0] - self.goal_offset - cube[:, 0]).clamp(min=0)
        push = torch.stack([tcp[:, 0] + lack, cube[:, 1], torch.full_like(lack, half)], 1)
        targets = [
            (0, _pose(above, q), closed),
            (1, _pose(start, q), closed),
            (2, _pose(push, q), closed, self.push_speed),
        ]
        return self.dispatch(targets)


class StackCubeExpert(_StockExpert):
    """Grasp cube A from above across two faces, lift it clear of cube B, set it on B and let go.

    Phases: 0 reach 4 cm above the grasp, 1 descend (back to 0 if a finger sets down on a cube), 2 close,
    3 lift, 4 carry A to ``carry_gap`` above its resting place on B, 5 lower it to ``place_gap``
    above, 6 open, 7 retreat upwards.
    """

    env_id = "StackCube-v1"
    fine_from = NO_INTEGRAL
    lift = 0.08  # phase 3 ends at 0.6 x lift = 4.8 cm up: A's bottom then clears B's 4 cm top
    close_steps = 3  # the fingers close on a 4 cm cube in 2 steps
    carry_gap = 0.02  # m above the resting place while moving over B
    place_gap = 0.002  # m above it when the gripper opens: A drops that far and stays static
    open_steps = 3  # steps holding still while the fingers open, before the retreat
    # The fingers open only to ``ajar`` per side on the way down: 1 cm clear of A's faces, and so
    # 1 cm further from a B standing beside A than fully open, which spares most long wrist turns.
    ajar = 0.03  # m per finger (the gripper's joint range is -0.01 to 0.04 m)
    finger_margin = 0.0125  # m around B's top that a fingertip (1.75 cm wide, 1.5 cm thick) must miss
    descend_steps = 6  # a clear descent of 4 cm takes 3-4 steps; still above A after this many, it is blocked

    def __init__(self, env, seed: int = 0, action_noise: float = 0.0):
        super().__init__(env, seed=seed, action_noise=action_noise)
        self._release_raw = torch.zeros(self.n, 7, device=self.device)

    def grasp_pose(self) -> Pose:
        """TCP grasp pose: top-down at A's centre, across the pair of A's faces that turns the wrist least and misses B.

        The open fingertips stand ``ajar`` to ``ajar + 1.5 cm`` either side of A's centre; where one would
        come down on B's top (B right beside A, facing the fingers) that pair is ruled out, as the
        motion-planning solution rejects grasps that collide, at the cost of a longer wrist turn.
        """
        u = self.env
        a, b = u.cubeA.pose, u.cubeB.pose
        rot = a.to_transformation_matrix()[:, :3, :3]
        tcp_y = u.agent.tcp.pose.to_transformation_matrix()[:, :3, 1]
        faces = torch.stack([rot[:, :, 0], -rot[:, :, 0], rot[:, :, 1], -rot[:, :, 1]], 1)
        # Each face's finger in B's frame; a pair is blocked if either of its two fingers is.
        fingers = a.p[:, None] + (self.ajar + 0.0075) * faces  # [B, 4, 3]: fingertip centres
        b_rot = b.to_transformation_matrix()[:, :3, :3]
        local = torch.einsum("bji,bkj->bki", b_rot, fingers - b.p[:, None])
        hit = (local[..., :2].abs() < u.cube_half_size[0] + self.finger_margin).all(-1)
        blocked = hit | hit[:, [1, 0, 3, 2]]
        score = _alignment(faces, tcp_y) - 10 * blocked.float()
        return _pose(a.p, _best_top_down_q(faces, score))

    def latched_release(self) -> Pose:
        """The TCP pose where the gripper opened, tracked until then and frozen after.

        Once A is let go the measured grasp no longer exists, so the hand holds this pose instead.
        """
        holding = self.phase <= 5
        if holding.any():
            self._release_raw[holding] = self.env.agent.tcp.pose.raw_pose[holding]
        return Pose.create(self._release_raw.clone())

    def act(self) -> torch.Tensor:
        """Action ``[B, 7]`` for each env's phase."""
        u = self.env
        open_, closed = self.grippers()
        ajar = torch.full_like(open_, 2 * (self.ajar + 0.01) / 0.05 - 1)
        up = torch.tensor([0, 0, 1.0], device=self.device)

        grasp = self.latched_grasp()
        above = _pose(grasp.p + 0.04 * up, grasp.q)
        # The open fingers straddle the cube with 1 cm to spare a side, so the last of the wrist
        # turn can finish on the way down.
        self.advance_grasp(above, grasp, above_rot_tol=0.15, grasp_pos_tol=0.004, grasp_timeout=12)
        # A finger that sets down on a cube's top (the wrist turn swings the hand sideways, or B
        # stands closer than grasp_pose allows for) is pinned there and closing would miss A:
        # go back above and line up again.
        off = torch.linalg.norm(u.agent.tcp.pose.p[:, :2] - grasp.p[:, :2], dim=1)
        self._advance((self.clock > self.descend_steps) & (off > 0.004), 1, 0)

        a, b = u.cubeA.pose, u.cubeB.pose
        rest = b.p + 2 * u.cube_half_size[2] * up  # A's centre resting on B
        # A keeps the orientation it has in the hand: success asks for no yaw alignment with B.
        carried = _pose(rest + self.carry_gap * up, a.q)
        placed = _pose(rest + self.place_gap * up, a.q)
        err = a.p - carried.p
        self._advance((torch.linalg.norm(err[:, :2], dim=1) < 0.004) & (err[:, 2].abs() < 0.006), 4, 5)
        err = a.p - placed.p
        self._advance(((torch.linalg.norm(err[:, :2], dim=1) < 0.006) & (err[:, 2] < 0.002)) | (self.clock > 8), 5, 6)
        self._advance(self.clock >= self.open_steps, 6, 7)

        release = self.latched_release()
        to_carried = self.tcp_target_for(a, carried)
        targets = [
            (0, above, ajar),
            (1, grasp, ajar),
            (2, grasp, closed),
            (3, _pose(grasp.p + self.lift * up, to_carried.q), closed),
            (4, to_carried, closed),
            (5, self.tcp_target_for(a, placed), closed),
            (6, release, open_),
            (7, _pose(release.p + 0.05 * up, release.q), open_),
        ]
        return self.dispatch(targets)
