"""How long a new process takes to its first camera picture of our task, with and without SAPIEN's BRDF table.

SAPIEN computes a BRDF lookup table with a compute shader the first time a process renders; on the CPU
(lavapipe) that is most of the time to a first picture. Our tasks give their cameras a blank table instead
(``drem_maniskill/envs/rendering.py``: a scene without an environment map renders the same images with it).
Every CLI command, SAC run, sampler and evaluation process starts through this.

One run: ``gym.make("PegInHole-v1", obs_mode="rgb")`` (which resets, taking the first pictures), one more
observation, exit. ``--sapiens-table`` leaves SAPIEN's table in place. Compare them side by side in one call
(whole processes, paired runs, median ratio)::

    farm-bench -n 5 --timeout 600 --vs ".venv/bin/python bench/first_picture.py --sapiens-table" \\
        -- .venv/bin/python bench/first_picture.py

Measured numbers: ``docs/results/bench/first_picture.json``.
"""

from __future__ import annotations

import argparse
import warnings

import gymnasium as gym


def main(argv=None) -> None:
    """Make the env (its first pictures), take one more observation, print the mean pixel."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sapiens-table", action="store_true", help="let SAPIEN compute its BRDF table")
    parser.add_argument("--task", default="PegInHole-v1")
    args = parser.parse_args(argv)

    from drem_maniskill.envs import insertion_base

    if args.sapiens_table:
        insertion_base.skip_brdf_lut = lambda scene, cameras: 0
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        env = gym.make(args.task, obs_mode="rgb")
    obs = env.unwrapped.get_obs()
    print(float(obs["sensor_data"]["fixed_camera"]["rgb"].float().mean()))
    env.close()


if __name__ == "__main__":
    main()
