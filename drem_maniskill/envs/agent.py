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
from pathlib import Path

import numpy as np
from gymnasium import spaces

from mani_skill import PACKAGE_ASSET_DIR
from mani_skill.agents.controllers import deepcopy_dict
from mani_skill.agents.controllers.base_controller import BaseController, ControllerConfig
from mani_skill.agents.registration import register_agent
from mani_skill.agents.robots.panda.panda import Panda

from drem_maniskill._cache import cached_text_file

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
    """Finger target below any part's half-width, so the fingers press on the part."""
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


@register_agent()
class PandaInsertion(Panda):
    """Panda with arm-only control modes and a gripper that keeps holding the part."""

    uid = "panda_insertion"
    urdf_path = str(FULL_URDF)
    render_style = "lean"

    def _load_articulation(self, initial_pose=None):
        # The render style is chosen per env; the env sets it on the agent class before loading.
        self.urdf_path = lean_urdf_path() if type(self).render_style == "lean" else str(FULL_URDF)
        super()._load_articulation(initial_pose)

    @property
    def _controller_configs(self):
        configs = super()._controller_configs
        hold = HoldGripperControllerConfig(self.gripper_joint_names)
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
