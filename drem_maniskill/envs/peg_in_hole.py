"""PegInHole-v1: insert a held round peg into a round hole with 2.4 mm clearance."""

from __future__ import annotations

import numpy as np
import sapien

from mani_skill.utils.registration import register_env

from drem_maniskill.envs.geometry import add_block_with_bore, prism_obj
from drem_maniskill.envs.insertion_base import InsertionEnv


@register_env("PegInHole-v1", max_episode_steps=50)
class PegInHoleEnv(InsertionEnv):
    """
    **Task Description:**
    A Panda holds a round peg (20 mm diameter, 100 mm long, 75 mm of it below the fingertips)
    above a block with a round hole 40 mm deep, and must insert the peg. The hole's diameter is
    the peg's plus ``clearance`` (default 2.4 mm, as in the paper). Actions are end-effector
    twists (``pd_ee_delta_pose``, at most 2 cm and 0.05 rad per step) at 5 Hz over 100 Hz physics.

    **Geometry as built:** the peg is a 32-sided convex prism with its vertices on the 10 mm
    radius (its flats are 0.048 mm inside it). The hole is a ring of 32 boxes whose inner faces
    are tangent to the nominal hole radius ``10 mm + clearance/2``, so the bore is a 32-gon that
    is nowhere narrower than the nominal circle and at most 0.054 mm wider in its corners (for
    the default clearance). The radial gap is thus 1.2 mm at its narrowest, the nominal value.

    **Randomizations (per episode, reproducible from the seed):**
    - the block's xy position (+-2 cm) and yaw (+-15 deg) on the floor;
    - the peg tip's start: xy offset from the hole axis (+-2 cm), height 45-70 mm above the
      block, yaw (+-10 deg) -- always inside the start region;
    - the colours of the peg and of the block (``randomize_colors=True``, the default).

    **Start region:** the peg tip more than 30 mm above the block's top face
    (``env.unwrapped.in_start_region()``).

    **Success Conditions:**
    - the peg tip is at least 80 % of the hole depth below the top face, inside the bore
      (tip within 1.5 mm of the hole axis) and the peg is tilted less than 10 deg.

    **Rewards:** ``sparse`` (success), ``dense`` (staged: reach above the hole, align,
    insert, success = 6), ``normalized_dense`` (``dense`` / 6), ``none``.
    """

    env_id = "PegInHole-v1"
    default_clearance = 0.0024
    peg_radius = 0.010
    peg_length = 0.100
    hole_depth = 0.040
    part_length_below_tcp = 0.075
    grip_half_width = 0.010
    base_thickness = 0.010
    socket_height = base_thickness + hole_depth
    wall = 0.020
    segments = 32
    part_radial_tolerance = 0.0015
    yaw_symmetry = 0

    def _add_part_shapes(self, builder, material):
        builder.add_convex_collision_from_file(prism_obj(self.peg_radius, self.peg_length, self.segments))
        # Cylinder visuals are along x; turn them to the part's z axis.
        builder.add_cylinder_visual(
            sapien.Pose([0, 0, self.peg_length / 2], [np.sqrt(0.5), 0, -np.sqrt(0.5), 0]),
            self.peg_radius, self.peg_length / 2, material=material,
        )

    @property
    def side_contact(self) -> float:
        """Tip-to-axis distance along the socket's x where the peg touches the block's side."""
        return self.peg_radius + self.clearance / 2 + self.wall + self.peg_radius

    def _add_socket_shapes(self, builder, material):
        hole_radius = self.peg_radius + self.clearance / 2
        add_block_with_bore(builder, hole_radius, self.segments, self.hole_depth, self.wall, self.base_thickness,
                            material)
