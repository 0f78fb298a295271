"""USBInsertion-v1: insert a held USB-A plug into a keyed receptacle with 1.0 mm clearance."""

from __future__ import annotations

import numpy as np
import sapien

from mani_skill.utils.registration import register_env

from drem_maniskill.envs.insertion_base import InsertionEnv


@register_env("USBInsertion-v1", max_episode_steps=50)
class USBInsertionEnv(InsertionEnv):
    """
    **Task Description:**
    A Panda holds a USB-A plug (metal shell 12.0 x 4.5 mm, 12 mm long, on a 16 x 8 x 33 mm
    body) above a receptacle and must plug it in. The receptacle's opening is the shell plus
    ``clearance`` (default 1.0 mm, as in the paper) in width and height: 13.0 x 5.5 mm. Like a
    real USB-A port it is keyed: a 0.75 mm tongue stands off-centre in the opening and fits only
    into the empty half of the plug's shell, so the plug enters one way up only (flipped by
    180 deg, its insulator block lands on the tongue). Actions are end-effector twists
    (``pd_ee_delta_pose``, at most 2 cm and 0.05 rad per step) at 5 Hz over 100 Hz physics.

    **Geometry as built:** boxes only, exact: shell walls 0.4 mm, tongue 10 x 0.75 mm at
    0.55-1.30 mm off the centre line, plug cavity 0.0-1.85 mm. The tongue clears the plug's
    cavity wherever the 1 mm clearance lets the plug sit, and overlaps the insulator wherever
    a flipped plug could sit.

    **Randomizations (per episode, reproducible from the seed):**
    - the receptacle's xy position (+-2 cm) and yaw (+-15 deg) on the floor;
    - the plug tip's start: xy offset (+-2 cm), height 45-70 mm above the receptacle, yaw
      error (+-10 deg) -- always inside the start region;
    - the colours of the plug body and of the receptacle (``randomize_colors=True``).

    **Start region:** the plug tip more than 30 mm above the receptacle's top face.

    **Success Conditions:**
    - the plug is at least 80 % of the 12 mm shell length inside the opening, its tip within
      0.8 mm of the opening's axis, yaw error below 10 deg, tilt below 10 deg.

    **Rewards:** ``sparse``, ``dense`` (staged: reach, align axis and yaw, insert,
    success = 6), ``normalized_dense`` (``dense`` / 6), ``none``.
    """

    env_id = "USBInsertion-v1"
    default_clearance = 0.0010
    shell = (0.012, 0.0045)  # width (x), height (y)
    shell_length = 0.012
    wall = 0.0004
    body = (0.016, 0.008, 0.033)
    cavity_top = 0.00185  # plug cavity: y in [0, cavity_top] (insulator below)
    tongue_y = (0.00055, 0.0013)
    tongue_half_width = 0.005
    hole_depth = shell_length
    port_depth = 0.013
    base_thickness = 0.017
    socket_height = base_thickness + port_depth
    housing_wall = 0.006
    part_length_below_tcp = 0.032
    grip_half_width = body[1] / 2
    part_radial_tolerance = 0.0008
    yaw_symmetry = 1
    max_yaw_error = np.deg2rad(10)
    fixed_camera_scale = 0.6

    def _add_part_shapes(self, builder, material):
        metal = sapien.render.RenderMaterial(base_color=[0.75, 0.75, 0.78, 1], metallic=0.8, roughness=0.3)
        insulator = sapien.render.RenderMaterial(base_color=[0.1, 0.1, 0.1, 1])
        w, h, t, length = self.shell[0] / 2, self.shell[1] / 2, self.wall / 2, self.shell_length / 2
        boxes = [
            # shell: top, bottom, left, right walls
            ([0, h - t, length], [w, t, length], metal),
            ([0, -h + t, length], [w, t, length], metal),
            ([w - t, 0, length], [t, h - 2 * t, length], metal),
            ([-w + t, 0, length], [t, h - 2 * t, length], metal),
            # insulator block filling the lower half of the cavity (the key)
            ([0, (-h + 2 * t) / 2, length], [w - 2 * t, (h - 2 * t) / 2, length], insulator),
            # overmoulded body the gripper holds
            (
                [0, 0, self.shell_length + self.body[2] / 2],
                [self.body[0] / 2, self.body[1] / 2, self.body[2] / 2],
                material,
            ),
        ]
        for p, half, mat in boxes:
            builder.add_box_collision(sapien.Pose(p), half)
            builder.add_box_visual(sapien.Pose(p), half, material=mat)

    @property
    def side_contact(self) -> float:
        """Tip-to-axis distance along the socket's x where the plug's shell touches the block's side."""
        return (self.shell[0] + self.clearance) / 2 + self.housing_wall + self.shell[0] / 2

    def _add_socket_shapes(self, builder, material):
        ow = (self.shell[0] + self.clearance) / 2  # half opening
        oh = (self.shell[1] + self.clearance) / 2
        hw = self.housing_wall
        depth, base = self.port_depth, self.base_thickness
        z = base + depth / 2
        dark = sapien.render.RenderMaterial(base_color=[0.08, 0.08, 0.08, 1])
        boxes = [
            ([0, 0, base / 2], [ow + hw, oh + hw, base / 2], material),
            ([0, oh + hw / 2, z], [ow + hw, hw / 2, depth / 2], material),
            ([0, -oh - hw / 2, z], [ow + hw, hw / 2, depth / 2], material),
            ([ow + hw / 2, 0, z], [hw / 2, oh, depth / 2], material),
            ([-ow - hw / 2, 0, z], [hw / 2, oh, depth / 2], material),
        ]
        # The tongue stands on the floor of the port, 3 mm short of the opening.
        tongue_top = base + depth - 0.003
        tongue_half = [self.tongue_half_width, (self.tongue_y[1] - self.tongue_y[0]) / 2, (tongue_top - base) / 2]
        boxes.append(([0, sum(self.tongue_y) / 2, (base + tongue_top) / 2], tongue_half, dark))
        for p, half, mat in boxes:
            builder.add_box_collision(sapien.Pose(p), half)
            builder.add_box_visual(sapien.Pose(p), half, material=mat)
