"""The Panda arm that our insertion tasks use: ManiSkill's Panda holding a part.

Differences from ManiSkill's ``panda``:

* The gripper is not part of the action. The robot starts holding the part and must keep it,
  so the fingers are held closed by a fixed PD target (``HoldGripperController``) and every
  control mode is arm-only: ``pd_ee_delta_pose`` is the 6-d end-effector twist of the paper.
* ``pd_ee_delta_pose`` moves at most 2 cm and 0.05 rad per control step (10 cm/s and
  0.25 rad/s at 5 Hz), fine enough for millimetre clearances.
* The lean render style draws each link with its collision mesh (a few hundred triangles)
  instead of the textured visual mesh (about a megabyte each), which is what makes CPU
  rendering fast. The kinematics are unchanged.
"""

from __future__ import annotations

import re
from copy import deepcopy
from dataclasses import dataclass
from typing import Callable, Optional
from pathlib import Path

import numpy as np
import sapien
from gymnasium import spaces

from mani_skill import PACKAGE_ASSET_DIR
from mani_skill.agents.controllers import deepcopy_dict
from mani_skill.agents.controllers.base_controller import BaseController, ControllerConfig
from mani_skill.agents.registration import register_agent
from mani_skill.agents.robots.panda.panda import Panda
from mani_skill.utils import sapien_utils
from mani_skill.utils.structs import Articulation

from drem_maniskill.utils.cache import cached_text_file

FULL_URDF = Path(PACKAGE_ASSET_DIR) / "robots/panda/panda_v2.urdf"

# Per control step at 5 Hz: fine enough to place a peg within its 1.2 mm radial clearance.
EE_POS_LIMIT = 0.02
EE_ROT_LIMIT = 0.05


class HoldGripperController(BaseController):
    """Keeps the fingers at a fixed closing target; takes no action."""

    config: "HoldGripperControllerConfig"
    sets_target_qpos = True
    sets_target_qvel = False

    def _initialize_action_space(self):
        self.single_action_space = spaces.Box(np.empty(0), np.empty(0), dtype=np.float32)

    def set_drive_property(self):
        for joint in self.joints:
            joint.set_drive_properties(
                self.config.stiffness, self.config.damping, force_limit=self.config.force_limit
            )
            joint.set_friction(0.0)

    def reset(self):
        super().reset()
        target = self.qpos.new_full(self.qpos.shape, self.config.target)
        self.articulation.set_joint_drive_targets(target, self.joints, self.active_joint_indices)

    def set_action(self, action):
        pass

    def before_simulation_step(self):
        pass


@dataclass
class HoldGripperControllerConfig(ControllerConfig):
    target: float = -0.005
    """Finger joint target: the held part's ``finger_target`` (its surface). Fingers and part do not
    collide (one rigid hand), so the target alone decides where the fingers rest; -0.005 (fully
    closed) only for a robot loaded without a part."""
    stiffness: float = 1e3
    damping: float = 1e2
    force_limit: float = 20.0
    controller_cls = HoldGripperController


def lean_urdf_path() -> str:
    """Path of a copy of Panda's URDF whose visuals are its collision meshes (made once)."""
    text = FULL_URDF.read_text()
    mesh_dir = FULL_URDF.parent / "franka_description/meshes"
    # Visual glb files carry textures and ~20k triangles per link; the collision STLs are coarse.
    text = re.sub(r"franka_description/meshes/visual/(\w+)\.glb", r"franka_description/meshes/collision/\1.stl", text)
    text = text.replace("franka_description/meshes/", f"{mesh_dir}/")
    return cached_text_file("panda_lean", ".urdf", text)


@dataclass
class HeldPart:
    """The part the hand holds: a rigid link fixed to ``panda_hand`` at ``pose_in_hand``."""

    pose_in_hand: sapien.Pose
    add_shapes: Callable  # add_shapes(link_builder, env_index): adds collision and visual shapes
    finger_target: Optional[float] = None  # finger joint position that rests on the part's surface
    name: str = "held_part"


@register_agent()
class PandaInsertion(Panda):
    """Panda with arm-only control modes, holding the task's part as a link of its hand."""

    uid = "panda_insertion"
    urdf_path = str(FULL_URDF)
    # Set by the env right before it loads the agent (ManiSkill builds agents from the class).
    render_style = "lean"
    held_part: Optional[HeldPart] = None

    def _load_articulation(self, initial_pose=None):
        # A rigid part must be part of the articulation: joints to separate actors yield under
        # insertion forces (millimetres at 30-60 N in PhysX), a fixed link does not.
        self.urdf_path = lean_urdf_path() if type(self).render_style == "lean" else str(FULL_URDF)
        part = type(self).held_part
        # Kept here: the controllers are made now and again whenever the control mode changes.
        self.finger_target = part.finger_target if part is not None and part.finger_target is not None else None

        def build(scene_idxs):
            loader = self.scene.create_urdf_loader()
            loader.name = f"{self.uid}-agent-{self._agent_idx}" if self._agent_idx is not None else self.uid
            loader.fix_root_link = self.fix_root_link
            loader.load_multiple_collisions_from_file = self.load_multiple_collisions
            loader.disable_self_collisions = self.disable_self_collisions
            if self.urdf_config is not None:
                config = sapien_utils.parse_urdf_config(self.urdf_config)
                sapien_utils.check_urdf_config(config)
                sapien_utils.apply_urdf_config(loader, config)
            builder = loader.parse(self.urdf_path)["articulation_builders"][0]
            if part is not None:
                hand = next(b for b in builder.link_builders if b.name == "panda_hand")
                link = builder.create_link_builder(hand)
                link.set_name(part.name)
                link.set_joint_name(f"{part.name}_joint")
                link.set_joint_properties("fixed", [], part.pose_in_hand, sapien.Pose())
                part.add_shapes(link, None if scene_idxs is None else scene_idxs[0])
            builder.initial_pose = initial_pose
            if scene_idxs is not None:
                builder.set_scene_idxs(scene_idxs)
                builder.set_name(f"{self.uid}-agent-{self._agent_idx}-{scene_idxs}")
            return builder.build()

        if self.build_separate:
            # One articulation per sub-scene, so each env has its own part materials to recolour.
            arts = []
            for i in range(self.scene.num_envs):
                art = build([i])
                self.scene.remove_from_state_dict_registry(art)
                arts.append(art)
            self.robot = Articulation.merge(arts, name=f"{self.uid}-agent-{self._agent_idx}", merge_links=True)
            self.scene.add_to_state_dict_registry(self.robot)
        else:
            self.robot = build(None)
        self.robot_link_names = [link.name for link in self.robot.get_links()]

    @property
    def _controller_configs(self):
        configs = super()._controller_configs
        hold = HoldGripperControllerConfig(self.gripper_joint_names)
        if getattr(self, "finger_target", None) is not None:
            hold.target = self.finger_target
        out = {}
        for mode, cfg in configs.items():
            arm = deepcopy(cfg["arm"])
            # Kinematics read the URDF only for joints and frames, which the lean copy keeps.
            if hasattr(arm, "urdf_path"):
                arm.urdf_path = str(FULL_URDF)
            if mode in ("pd_ee_delta_pose", "pd_ee_target_delta_pose"):
                arm.pos_lower, arm.pos_upper = -EE_POS_LIMIT, EE_POS_LIMIT
                arm.rot_lower, arm.rot_upper = -EE_ROT_LIMIT, EE_ROT_LIMIT
            elif mode in ("pd_ee_delta_pos", "pd_ee_target_delta_pos"):
                arm.pos_lower, arm.pos_upper = -EE_POS_LIMIT, EE_POS_LIMIT
            out[mode] = dict(arm=arm, gripper=deepcopy(hold))
        return deepcopy_dict(out)
