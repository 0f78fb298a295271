"""SquarePegInHole-v1: insert a held square peg into a square hole with 1.0 mm clearance."""

from __future__ import annotations

import numpy as np
import sapien

from mani_skill.utils.registration import register_env

from drem_maniskill.envs.geometry import add_block_with_bore, prism_obj, z_rotation
from drem_maniskill.envs.insertion_base import InsertionEnv


@register_env("SquarePegInHole-v1", max_episode_steps=50)
class SquarePegInHoleEnv(InsertionEnv):
    """
    **Task Description:**
    A Panda holds a square peg (16 x 16 mm, 90 mm long, 65 mm of it below the fingertips, the
    fingers on two of its faces) above a block with a square hole 30 mm deep, and must insert the
    peg. The hole's side is the peg's plus ``clearance`` (default 1.0 mm). The peg fits every
    quarter turn, so its yaw must be within 10 deg of one of four. Actions are end-effector twists
    (``pd_ee_delta_pose``, at most 2 cm and 0.05 rad per step) at 5 Hz over 100 Hz physics.

    **Geometry as built:** exact: the peg is a square convex prism, the hole four box walls 20 mm
    thick on a 10 mm base plate.

    **Randomizations (per episode, reproducible from the seed):**
    - the block's xy position (+-2 cm) and yaw (+-15 deg) on the floor;
    - the peg tip's start: xy offset from the hole axis (+-2 cm), height 45-70 mm above the
      block, yaw (+-10 deg) -- always inside the start region;
    - the colours of the peg and of the block (``randomize_colors=True``, the default).

    **Start region:** the peg tip more than 30 mm above the block's top face.

    **Success Conditions:**
    - the peg tip is at least 80 % of the hole depth below the top face, within 0.8 mm of the
      hole axis, its yaw within 10 deg of a quarter turn and its tilt below 10 deg.

    **Rewards:** ``sparse`` (success), ``dense`` (staged: reach above the hole, align axis and
    yaw, insert, success = 6), ``normalized_dense`` (``dense`` / 6), ``engineered``, ``drem``, ``none``.
    """

    env_id = "SquarePegInHole-v1"
    default_clearance = 0.0010
    peg_side = 0.016
    peg_length = 0.090
    hole_depth = 0.030
    part_length_below_tcp = 0.065
    grip_half_width = peg_side / 2
    base_thickness = 0.010
    socket_height = base_thickness + hole_depth
    wall = 0.020
    part_radial_tolerance = 0.0008
    yaw_symmetry = 4
    max_yaw_error = np.deg2rad(10)
    contact_offset = 0.001  # below the radial gap

    def _add_part_shapes(self, builder, material):
        # A convex prism (its corners on the diagonals), not a box: PhysX's box-box contact catches a box peg's bottom
        # edge on the hole's rim where 0.5 mm separate them.
        shape = prism_obj(self.peg_side / np.sqrt(2), self.peg_length, 4)
        builder.add_convex_collision_from_file(shape, pose=sapien.Pose(q=z_rotation(np.pi / 4)))
        half = [self.peg_side / 2, self.peg_side / 2, self.peg_length / 2]
        builder.add_box_visual(sapien.Pose([0, 0, self.peg_length / 2]), half, material=material)

    @property
    def side_contact(self) -> float:
        """Tip-to-axis distance along the socket's x where the peg touches the block's side."""
        return (self.peg_side + self.clearance) / 2 + self.wall + self.peg_side / 2

    def _add_socket_shapes(self, builder, material):
        inner = (self.peg_side + self.clearance) / 2
        add_block_with_bore(builder, inner, 4, self.hole_depth, self.wall, self.base_thickness, material)
