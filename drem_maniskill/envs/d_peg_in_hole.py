"""DPegInHole-v1: insert a held D-shaped peg into a keyed D-shaped hole with 1.2 mm clearance."""

from __future__ import annotations

import numpy as np
import sapien

from mani_skill.utils.registration import register_env

from drem_maniskill.envs.geometry import d_prism_obj
from drem_maniskill.envs.peg_in_hole import PegInHoleEnv


@register_env("DPegInHole-v1", max_episode_steps=50)
class DPegInHoleEnv(PegInHoleEnv):
    """
    **Task Description:**
    A Panda holds a D-shaped peg (a round peg 20 mm across with one flat 6 mm from its axis,
    90 mm long, 65 mm of it below the fingertips) above a block with a D-shaped hole 35 mm deep,
    and must insert the peg. The hole is the peg grown by ``clearance`` / 2 all round (default
    1.2 mm on the diameter). The hole is keyed: its flat side admits the peg one way round only,
    and a peg turned more than about 4.5 deg from it catches the flat's edge. Actions are
    end-effector twists (``pd_ee_delta_pose``, at most 2 cm and 0.05 rad per step) at 5 Hz over
    100 Hz physics.

    **Geometry as built:** the peg is a convex prism, a 32-gon arc closed by the flat. The hole
    is PegInHole-v1's (a 32-sided ring of boxes tangent to the round) and one box whose face is
    the hole's flat.

    **Randomizations (per episode, reproducible from the seed):**
    - the block's xy position (+-2 cm) and yaw (+-15 deg) on the floor;
    - the peg tip's start: xy offset from the hole axis (+-2 cm), height 45-70 mm above the
      block, yaw (+-10 deg) -- always inside the start region;
    - the colours of the peg and of the block (``randomize_colors=True``, the default).

    **Start region:** the peg tip more than 30 mm above the block's top face.

    **Success Conditions:**
    - the peg tip is at least 80 % of the hole depth below the top face, within 1.0 mm of the
      hole axis, its yaw within 10 deg and its tilt below 10 deg.

    **Rewards:** ``sparse`` (success), ``dense`` (staged: reach above the hole, align axis and
    yaw, insert, success = 6), ``normalized_dense`` (``dense`` / 6), ``engineered``, ``drem``, ``none``.
    """

    env_id = "DPegInHole-v1"
    default_clearance = 0.0012
    peg_radius = 0.010
    flat = 0.006  # the flat's distance from the axis, on the part's +x
    peg_length = 0.090
    hole_depth = 0.035
    part_length_below_tcp = 0.065
    grip_half_width = peg_radius  # the fingers (along y) hold the round, not the flat
    base_thickness = 0.010
    socket_height = base_thickness + hole_depth
    wall = 0.020
    segments = 32
    part_radial_tolerance = 0.0010
    yaw_symmetry = 1
    max_yaw_error = np.deg2rad(10)
    contact_offset = 0.001  # below the radial gap

    def _add_part_shapes(self, builder, material):
        shape = d_prism_obj(self.peg_radius, self.flat, self.peg_length, self.segments)
        builder.add_convex_collision_from_file(shape)
        builder.add_visual_from_file(shape, material=material)

    def _add_socket_shapes(self, builder, material):
        super()._add_socket_shapes(builder, material)  # the round hole
        hole_radius = self.peg_radius + self.clearance / 2
        # The key: fills the round beyond the hole's flat (inside the ring's walls wherever it reaches past the round).
        face = self.flat + self.clearance / 2
        key_half = [(hole_radius + self.wall / 2 - face) / 2, hole_radius, self.hole_depth / 2]
        key = sapien.Pose([face + key_half[0], 0, self.base_thickness + self.hole_depth / 2])
        builder.add_box_collision(key, key_half)
        builder.add_box_visual(key, key_half, material=material)
