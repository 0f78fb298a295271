"""HexPegInTiltedHole-v1: insert a held hexagonal peg into a hexagonal hole leaning 25 deg, with 1.5 mm clearance."""

from __future__ import annotations

import numpy as np
import sapien

from mani_skill.utils.registration import register_env

from drem_maniskill.envs.geometry import PosedBuilder, add_block_with_bore, prism_obj, z_rotation
from drem_maniskill.envs.insertion_base import InsertionEnv


@register_env("HexPegInTiltedHole-v1", max_episode_steps=50)
class HexPegInTiltedHoleEnv(InsertionEnv):
    """
    **Task Description:**
    A Panda holds a hexagonal peg (18 mm across the flats, 90 mm long, 65 mm of it below the
    fingertips, the fingers on two flats) in front of a block whose hexagonal hole, 30 mm deep,
    leans 25 deg from vertical towards the robot, and must insert the peg along the hole's axis.
    The hole is the peg grown by ``clearance`` / 2 on every flat (default 1.5 mm across the
    flats). The peg fits every sixth of a turn. Actions are end-effector twists
    (``pd_ee_delta_pose``, at most 2 cm and 0.05 rad per step) at 5 Hz over 100 Hz physics.

    **Geometry as built:** exact: the peg is a hexagonal convex prism, the hole six box walls
    20 mm thick on a 10 mm base plate; the block stands tilted on a pedestal, its base 14 mm above
    the floor.

    **Randomizations (per episode, reproducible from the seed):**
    - the block's xy position (+-2 cm) and yaw (+-15 deg) on the floor;
    - the peg tip's start, in the hole's frame: offset across the axis (+-2 cm), 45-70 mm out
      along the axis, yaw about it (+-10 deg), the peg parallel to the axis -- always inside the
      start region;
    - the colours of the peg and of the block (``randomize_colors=True``, the default).

    **Start region:** the peg tip more than 30 mm out from the hole's top face, along its axis.

    **Success Conditions:**
    - the peg tip is at least 80 % of the hole depth below the top face along the axis, within
      1.0 mm of it, its yaw within 10 deg of a sixth of a turn and its tilt from the axis below 10 deg.

    **Rewards:** ``sparse`` (success), ``dense`` (staged: reach above the hole, align axis and
    yaw, insert, success = 6), ``normalized_dense`` (``dense`` / 6), ``engineered``, ``drem``, ``none``.
    """

    env_id = "HexPegInTiltedHole-v1"
    default_clearance = 0.0015
    peg_apothem = 0.009  # centre to flat
    peg_length = 0.090
    hole_depth = 0.030
    part_length_below_tcp = 0.065
    grip_half_width = peg_apothem
    base_thickness = 0.010
    socket_height = base_thickness + hole_depth
    wall = 0.020
    part_radial_tolerance = 0.0010
    yaw_symmetry = 6
    max_yaw_error = np.deg2rad(10)
    contact_offset = 0.001  # below the radial gap
    socket_tilt = np.deg2rad(25)
    socket_lift = 0.014  # the tilted base's low edge (30 mm from the axis) clears the floor
    # Flats face +-y (the fingers) and four more directions 60 deg apart.
    flat_phase = np.pi / 6

    def _add_part_shapes(self, builder, material):
        # A convex prism for contacts (corners at 0, 60, ... deg, so its flats face flat_phase + k 60 deg); three
        # boxes make the same hexagon for its picture.
        builder.add_convex_collision_from_file(prism_obj(self.peg_apothem / np.cos(np.pi / 6), self.peg_length, 6))
        side = 2 * self.peg_apothem * np.tan(np.pi / 6)
        half = [self.peg_apothem, side / 2, self.peg_length / 2]
        for k in range(3):
            pose = sapien.Pose([0, 0, self.peg_length / 2], z_rotation(self.flat_phase + k * np.pi / 3))
            builder.add_box_visual(pose, half, material=material)

    @property
    def side_contact(self) -> float:
        """Tip-to-axis distance along the socket's x where the peg touches the block's side."""
        return self.peg_apothem + self.clearance / 2 + self.wall + self.peg_apothem

    def _add_socket_shapes(self, builder, material):
        inner = self.peg_apothem + self.clearance / 2
        block = PosedBuilder(builder, self._block_in_socket_actor())
        outer = add_block_with_bore(block, inner, 6, self.hole_depth, self.wall, self.base_thickness, material,
                                    phase=self.flat_phase)
        # A pedestal under the tilted base, upright on the floor.
        stand = [outer * np.cos(self.socket_tilt), outer, self.socket_lift / 2]
        builder.add_box_collision(sapien.Pose([0, 0, self.socket_lift / 2]), stand)
        builder.add_box_visual(sapien.Pose([0, 0, self.socket_lift / 2]), stand, material=material)
