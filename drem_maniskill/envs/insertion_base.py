"""Shared base of our contact-rich insertion tasks (PegInHole-v1, USBInsertion-v1).

A Panda stands at the world origin and holds a part above a socket that lies on the floor in
front of it. The part is a rigid link of the hand (added to the robot's articulation when it is
loaded), so it cannot slip or drop. Frames:

* the **socket frame** sits at the centre of the socket's opening on its top face, z up;
  the part goes in along -z;
* the **part frame** sits at the centre of the part's tip, z up (away from the tip). When the
  part is fully aligned, its frame and the socket frame have the same orientation.

Subclasses give the geometry (``_add_part_shapes``, ``_add_socket_shapes``, class constants) and, for a
keyed part, the orientation tolerance. Everything here is batched over ``num_envs``.
"""

from __future__ import annotations

from typing import Optional

import numpy as np
import sapien
import torch

from mani_skill.agents.controllers.utils.kinematics import Kinematics
from mani_skill.envs.sapien_env import BaseEnv
from mani_skill.sensors.camera import CameraConfig
from mani_skill.utils import sapien_utils
from mani_skill.utils.building.ground import build_ground
from mani_skill.utils.geometry.rotation_conversions import (
    quaternion_invert,
    quaternion_multiply,
    quaternion_to_matrix,
)
from mani_skill.utils.structs import Actor, Pose
from mani_skill.utils.structs.types import SceneConfig, SimConfig

from drem_maniskill.drem.mode import DREMRewardMode
from drem_maniskill.envs.agent import FULL_URDF, HeldPart, PandaInsertion
from drem_maniskill.envs.ft_sensor import WristFTSensor
from drem_maniskill.envs.geometry import y_rotation
from drem_maniskill.envs.insertion_rewards import InsertionRewards
from drem_maniskill.envs.placement import SocketPlacement, yaw_quat
from drem_maniskill.envs.task_state import TaskState

RENDER_STYLES = ("lean", "full")
# Group-2 collision bit on every robot link, held part included: no contact forces between
# links of one rigid hand (fingers and part).
_HELD_PART_BIT = 28

# Hand-frame (z towards the fingers) pose of the TCP, from Panda's URDF.
_TCP_IN_HAND = 0.1034
# Part frame in TCP frame: the TCP points down (z), the part frame points up.
_FLIP_X = [0.0, 1.0, 0.0, 0.0]


class InsertionEnv(InsertionRewards, DREMRewardMode, SocketPlacement, TaskState, BaseEnv):
    """Base class: a held part, a socket, two cameras and a wrist F/T sensor.

    Its mixins: the reward modes (``InsertionRewards``: ``REWARD_FUNCTIONS``), the socket's placement
    (``SocketPlacement``), the F/T observation and the task's state keys (``TaskState``).
    """

    SUPPORTED_ROBOTS = ["panda_insertion"]
    agent: PandaInsertion

    # --- geometry, set by subclasses (metres, radians) ---
    default_clearance: float = 0.0
    hole_depth: float = 0.0
    part_length_below_tcp: float = 0.0  # from the TCP to the part tip, along the approach axis
    grip_half_width: float = 0.0  # finger joint position that touches the part
    socket_height: float = 0.0  # socket top face above the floor
    part_radial_tolerance: float = 0.0  # tip-to-axis distance that still counts as "in the bore"
    side_contact: float = 0.0  # tip-to-axis distance along the socket's x where the part touches the block's side
    yaw_symmetry: int = 0  # 0: round part (yaw free); k: part repeats every 2*pi/k
    max_yaw_error: float = np.pi  # insertion tolerance on yaw (keyed parts)
    # The opening's axis leans from vertical by this (rad), towards the robot, and the block's base sits ``socket_lift``
    # (m) above the floor (``_block_in_socket_actor``, where a tilted task draws its block). Everything in the socket
    # frame (the success test, the policies, the start region) follows the axis.
    socket_tilt: float = 0.0
    socket_lift: float = 0.0
    # PhysX's contact offset (m). A small one keeps the many socket pieces from all generating contacts at once; one
    # wider than the part's radial gap lets the part's bottom edge catch on the opening's rim, centred and square to it
    # (a 0.75 mm gap at 4 mm: 3 of 20 expert episodes stuck there; at 1 mm, none).
    contact_offset: float = 0.004
    # Regions of the tip around the opening (socket frame), which the sampler's extra phases and the tree's report read
    # (``EnvAdapter.socket_geometry``). The blocks of both tasks are solid beyond ``opening_radius`` (the USB port's
    # housing reaches 8.75 mm, the plug's shell 2.25 mm more), so a tip lower than ``inserted_height`` and within it is
    # in the opening, and one lower and farther out is beside the socket.
    opening_radius: float = 0.01
    inserted_height: float = -0.001
    # A tip above this is on or over the face, not caught in the opening's mouth. A tip caught in the USB opening's
    # mouth rests 0.4-0.5 mm below the face, so the bound sits above that, just under the face.
    face_seed_height: float = -0.0002

    # --- randomization and start region ---
    socket_center = (0.55, 0.0)
    socket_xy_range = 0.02
    socket_yaw_range = np.deg2rad(15)
    start_xy_range = 0.02
    start_yaw_range = np.deg2rad(10)
    start_height_range = (0.045, 0.07)  # tip above the socket's top face
    start_region_height = 0.03  # tip higher than this above the socket top: "start region"
    color_range = (0.05, 0.95)  # part and socket RGB, uniform per channel (randomize_colors)
    success_depth_fraction = 0.8

    ft_link = "panda_hand"
    env_id: str = ""  # the registered id, for checking reward checkpoints
    fixed_camera_scale = 1.0  # distance of the fixed camera, relative to the peg task's

    def __init__(
        self,
        *args,
        robot_uids="panda_insertion",
        control_mode: Optional[str] = "pd_ee_delta_pose",
        clearance: Optional[float] = None,
        randomize_colors: bool = True,
        render_style: str = "lean",
        ft_history: int = 8,
        reconfiguration_freq: Optional[int] = None,
        engineered_kappa: float = 10.0,
        **kwargs,
    ):
        self.clearance = self._check_clearance(self.default_clearance if clearance is None else clearance)
        if render_style not in RENDER_STYLES:
            raise ValueError(f"render_style must be one of {RENDER_STYLES}, got {render_style!r}")
        if int(ft_history) < 1:
            raise ValueError(f"ft_history must be a positive number of readings, got {ft_history}")
        self.randomize_colors = bool(randomize_colors)
        self.render_style = render_style
        self.ft_history = int(ft_history)
        self.engineered_kappa = float(engineered_kappa)  # 1/m, for reward_mode="engineered"
        # Colours and poses change without rebuilding the scene, and a rebuild costs hundreds of milliseconds a reset.
        if reconfiguration_freq is None:
            reconfiguration_freq = 0
        super().__init__(
            *args,
            robot_uids=robot_uids,
            control_mode=control_mode,
            reconfiguration_freq=reconfiguration_freq,
            **kwargs,
        )

    def _check_clearance(self, clearance) -> float:
        try:
            value = float(clearance)
        except (TypeError, ValueError):
            value = float("nan")
        if not np.isfinite(value) or value <= 0 or value > 0.02:
            raise ValueError(
                f"clearance must be a positive diametral gap in metres below 0.02 "
                f"(the paper uses {self.default_clearance}), got {clearance!r}"
            )
        return value

    # ------------------------------------------------------------------ configuration
    @property
    def _default_sim_config(self):
        # Paper: torques at 100 Hz, policy at 5 Hz.
        return SimConfig(
            sim_freq=100,
            control_freq=5,
            scene_config=SceneConfig(contact_offset=self.contact_offset, solver_position_iterations=20),
        )

    @property
    def _default_sensor_configs(self):
        # From the side opposite the robot, so the arm does not hide the part or the socket.
        target = [self.socket_center[0], self.socket_center[1], self.socket_height + 0.03]
        k = self.fixed_camera_scale
        eye = [target[0] + 0.17 * k, target[1] - 0.13 * k, target[2] + 0.09 * k]
        fixed = CameraConfig("fixed_camera", sapien_utils.look_at(eye, target), 128, 128, np.deg2rad(40), 0.01, 10)
        # In the hand frame z points to the fingers: look past the fingertips at the part tip.
        tip = _TCP_IN_HAND + self.part_length_below_tcp
        wrist_pose = sapien_utils.look_at([0.055, 0.0, 0.05], [0.0, 0.0, tip + 0.04], up=[1, 0, 0])
        wrist = CameraConfig(
            "wrist_camera", wrist_pose, 128, 128, np.deg2rad(60), 0.01, 10,
            mount=self.agent.robot.links_map["panda_hand"],
        )
        return [fixed, wrist]

    @property
    def _default_human_render_camera_configs(self):
        target = [self.socket_center[0], self.socket_center[1], self.socket_height + 0.05]
        pose = sapien_utils.look_at([target[0] + 0.45, target[1] - 0.5, target[2] + 0.4], target)
        return CameraConfig("render_camera", pose, 384, 384, np.deg2rad(50), 0.01, 10)

    # ------------------------------------------------------------------ scene
    def _load_agent(self, options: dict):
        # The part is a link of the robot's hand; one material per env so colours can vary.
        self._part_materials = [
            sapien.render.RenderMaterial(base_color=[0.85, 0.45, 0.1, 1], roughness=0.5) for _ in range(self.num_envs)
        ]
        self.part_in_hand = sapien.Pose(p=[0, 0, _TCP_IN_HAND + self.part_length_below_tcp], q=_FLIP_X)

        def add_part_shapes(link_builder, env_index):
            self._add_part_shapes(link_builder, self._part_materials[env_index or 0])

        PandaInsertion.render_style = self.render_style
        # The fingers rest on the part's surface, as in a real grasp, from the first observation on.
        PandaInsertion.held_part = HeldPart(self.part_in_hand, add_part_shapes, finger_target=self.grip_half_width)
        try:
            super()._load_agent(options, sapien.Pose(), build_separate=True)
        finally:
            PandaInsertion.held_part = None

    def _load_lighting(self, options: dict):
        shadow = self.render_style == "full" and self.enable_shadow
        self.scene.set_ambient_light([0.35, 0.35, 0.35])
        self.scene.add_directional_light(
            [0.5, 0.3, -1], [1.2, 1.2, 1.2], shadow=shadow, shadow_scale=2, shadow_map_size=1024
        )
        if self.render_style == "full":
            self.scene.add_directional_light([0, 0, -1], [0.6, 0.6, 0.6])

    def _load_scene(self, options: dict):
        if self.render_style == "full":
            self.ground = build_ground(self.scene)
        else:
            builder = self.scene.create_actor_builder()
            builder.add_plane_collision(sapien.Pose(q=[0.7071068, 0, -0.7071068, 0]))
            builder.add_box_visual(
                sapien.Pose([0.3, 0, -0.005]), [1.0, 1.0, 0.005],
                material=sapien.render.RenderMaterial(base_color=[0.22, 0.24, 0.27, 1]),
            )
            builder.initial_pose = sapien.Pose()
            self.ground = builder.build_static(name="ground")

        # One socket per sub-scene so every env has its own render material to recolour.
        sockets = []
        self._socket_materials = []
        for i in range(self.num_envs):
            socket_mat = sapien.render.RenderMaterial(base_color=[0.2, 0.35, 0.75, 1], roughness=0.6)
            builder = self.scene.create_actor_builder()
            self._add_socket_shapes(builder, socket_mat)
            builder.set_scene_idxs([i])
            builder.initial_pose = sapien.Pose(p=[*self.socket_center, 0])
            sockets.append(builder.build_kinematic(name=f"socket-{i}"))
            self._socket_materials.append(socket_mat)
        self.socket = Actor.merge(sockets, name="socket")
        self.part = self.agent.robot.links_map["held_part"]
        # Fingers and part are links of one rigid hand: contacts between them would only fight.
        for link in self.agent.robot.links:
            link.set_collision_group_bit(2, _HELD_PART_BIT, 1)

    def _after_reconfigure(self, options: dict):
        super()._after_reconfigure(options)
        robot = self.agent.robot
        arm = getattr(self.agent, "arm_joint_names", None)
        joints = robot.active_joints_map
        self._arm_idx = torch.tensor([joints[n].active_index[0] for n in arm], device=self.device).long()
        self._finger_idx = torch.tensor(
            [joints[n].active_index[0] for n in self.agent.gripper_joint_names], device=self.device
        ).long()
        self._ik = Kinematics(str(FULL_URDF), "panda_hand_tcp", robot, self._arm_idx)
        self.ft = WristFTSensor(robot, self.ft_link, self.ft_history, self.device)

    # ------------------------------------------------------------------ episodes
    def _initialize_episode(self, env_idx: torch.Tensor, options: dict):
        with torch.device(self.device):
            b = len(env_idx)
            rng = self._batched_episode_rng[env_idx]
            # Socket on the floor: small xy and yaw jitter.
            xy_range, yaw_range = self.socket_xy_range, self.socket_yaw_range
            socket_xy = torch.as_tensor(rng.uniform(-xy_range, xy_range, size=(2,)), dtype=torch.float32)
            socket_yaw = torch.as_tensor(rng.uniform(-yaw_range, yaw_range), dtype=torch.float32)
            socket_pose = self._socket_pose_at(socket_xy + torch.tensor(self.socket_center), socket_yaw, torch.zeros(b))
            self.socket.set_pose(socket_pose)
            top = socket_pose * self._opening_in_socket_actor(b)

            # Part tip in the start region: above the opening with an xy offset and a yaw error.
            off = torch.zeros(b, 3)
            xy_range = self.start_xy_range
            off[:, :2] = torch.as_tensor(rng.uniform(-xy_range, xy_range, size=(2,)), dtype=torch.float32)
            off[:, 2] = torch.as_tensor(rng.uniform(*self.start_height_range), dtype=torch.float32)
            part_yaw = torch.as_tensor(rng.uniform(-self.start_yaw_range, self.start_yaw_range), dtype=torch.float32)
            part_pose = Pose.create_from_pq(top.p + off, yaw_quat(socket_yaw + part_yaw))
            if self.socket_tilt:  # the offset and the part lean with the opening's axis
                lean = top * Pose.create_from_pq(q=yaw_quat(-socket_yaw)) * Pose.create_from_pq(-top.p)
                part_pose = lean * part_pose
            tcp_target = part_pose * Pose.create(sapien.Pose(p=[0, 0, self.part_length_below_tcp], q=_FLIP_X))
            qpos = self._solve_ik(tcp_target, env_idx)
            self.agent.robot.set_qpos(qpos)
            self.agent.robot.set_qvel(torch.zeros_like(qpos))

            if self.randomize_colors:
                self.set_colors(rng.uniform(*self.color_range, size=(6,)), env_idx)
            self.ft.reset(env_idx)

    def set_colors(self, colors, env_idx=None) -> None:
        """Part and socket colours ``[b, 6]`` (part RGB, socket RGB, in [0, 1]) of envs ``env_idx`` (default: all).

        Colours are render materials, not physics: no state holds them, and changing them does
        not change what the next step does (the backward sampler recolours restored states).
        """
        # Not a hot path (resets, sampling): one material per sub-scene.
        colors = np.asarray(torch.as_tensor(colors).cpu(), dtype=np.float64).reshape(-1, 6)
        envs = range(self.num_envs) if env_idx is None else torch.as_tensor(env_idx).tolist()
        for k, i in enumerate(envs):
            self._part_materials[i].base_color = [*colors[k, :3], 1.0]
            self._socket_materials[i].base_color = [*colors[k, 3:], 1.0]

    def get_colors(self) -> torch.Tensor:
        """Part and socket colours ``[num_envs, 6]``."""
        rows = [[*p.base_color[:3], *s.base_color[:3]] for p, s in zip(self._part_materials, self._socket_materials)]
        return torch.tensor(rows, dtype=torch.float32)

    def _solve_ik(self, tcp_target: Pose, env_idx: torch.Tensor) -> torch.Tensor:
        """Full robot qpos ``[b, dof]`` that puts the TCP at ``tcp_target`` (robot base = world)."""
        rest = torch.as_tensor(self.agent.keyframes["rest"].qpos, dtype=torch.float32, device=self.device)
        q = rest.repeat(len(env_idx), 1)
        q[:, self._finger_idx] = self.grip_half_width
        if self._ik.use_gpu_ik:
            # One damped least-squares step per call: iterate to convergence.
            for _ in range(30):
                q[:, self._arm_idx] = self._ik.compute_ik(tcp_target, q)
        else:
            sol = self._ik.compute_ik(tcp_target, q)
            if sol is None:
                raise RuntimeError(f"IK failed for start pose {tcp_target.raw_pose.tolist()}; shrink the start region")
            q[:, self._arm_idx] = sol.to(q.dtype)
        return q

    # ------------------------------------------------------------------ task
    def _block_in_socket_actor(self) -> sapien.Pose:
        """Where the block's own frame (base at z = 0, opening up) sits in the socket actor's (on the floor)."""
        return sapien.Pose([0, 0, self.socket_lift], y_rotation(-self.socket_tilt))

    def _opening_in_socket_actor(self, count: int) -> Pose:
        """The socket frame (centre of the opening on its top face, axis z) in the socket actor's, ``count`` times."""
        # Read at every step by the success test and the rewards: built once per shape and kept (two thirds of the
        # socket frame's cost was building these tensors).
        key = (count, self.socket_lift, self.socket_tilt, self.socket_height, str(self.device))
        cached = self.__dict__.get("_opening_in_actor")
        if cached is None or cached[0] != key:
            opening = self._block_in_socket_actor() * sapien.Pose([0, 0, self.socket_height])
            pq = torch.tensor([[*opening.p, *opening.q]], dtype=torch.float32, device=self.device).repeat(count, 1)
            cached = self._opening_in_actor = (key, pq)
        return Pose.create(cached[1])

    def opening_pose(self) -> Pose:
        """World pose ``[num_envs]`` of the socket frame: the centre of the opening on its top face, the axis z."""
        return self.socket.pose * self._opening_in_socket_actor(self.num_envs)

    def axis_lean(self) -> torch.Tensor:
        """Rotation ``[num_envs, 3, 3]`` leaning the world's axes as the opening's axis leans (identity if upright)."""
        eye = torch.eye(3, device=self.device).expand(self.num_envs, 3, 3)
        if not self.socket_tilt:
            return eye
        socket = self.socket.pose.q
        lean = quaternion_multiply(self.opening_pose().q, quaternion_invert(socket))
        return quaternion_to_matrix(lean)

    def tip_pose_in_socket(self) -> Pose:
        """Pose of the part frame (tip) in the socket frame (top of the opening)."""
        return self.opening_pose().inv() * self.part.pose

    def in_start_region(self) -> torch.Tensor:
        """Bool ``[num_envs]``: the part tip is more than ``start_region_height`` above the socket."""
        return self.tip_pose_in_socket().p[:, 2] > self.start_region_height

    def orientation_errors(self, rel: Pose):
        """Tilt and absolute yaw error ``[B]`` (rad) of a part pose in the socket frame, as the success test reads."""
        rot = quaternion_to_matrix(rel.q)
        tilt = torch.arccos(rot[:, 2, 2].clamp(-1, 1))
        yaw = torch.atan2(rot[:, 1, 0], rot[:, 0, 0])
        if self.yaw_symmetry:
            period = 2 * np.pi / self.yaw_symmetry
            yaw = torch.remainder(yaw + period / 2, period) - period / 2
        else:
            yaw = torch.zeros_like(yaw)
        return tilt, yaw.abs()

    def evaluate(self):
        """The success test and the quantities the rewards read, per env."""
        rel = self.tip_pose_in_socket()
        depth = -rel.p[:, 2]
        radial = torch.linalg.norm(rel.p[:, :2], dim=1)
        tilt, yaw_err = self.orientation_errors(rel)
        in_bore = radial <= self.part_radial_tolerance
        aligned = in_bore & (yaw_err <= self.max_yaw_error) & (tilt <= np.deg2rad(10))
        success = aligned & (depth >= self.success_depth_fraction * self.hole_depth)
        return dict(
            success=success,
            insertion_depth=depth,
            depth_fraction=(depth / self.hole_depth).clamp(0, 1),
            radial_offset=radial,
            tilt_error=tilt,
            yaw_error=yaw_err,
            is_aligned=aligned,
            tip_in_socket=rel.p,
            in_start_region=rel.p[:, 2] > self.start_region_height,
        )
