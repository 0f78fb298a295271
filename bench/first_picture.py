"""How long a new process takes to its first camera picture of a task, with and without SAPIEN's BRDF table.

SAPIEN computes a BRDF lookup table with a compute shader the first time a process renders; on the CPU
(lavapipe) that is most of the time to a first picture. Once ``drem_maniskill`` is imported, every ManiSkill env's
cameras get a blank table instead (``drem_maniskill/envs/rendering.py``: a scene without an environment map renders
the same images with it). Every CLI command, SAC run, sampler and evaluation process starts through this.

One run: ``gym.make(TASK, obs_mode="rgb")`` (``--task``, PegInHole-v1 by default; it resets, taking the first
pictures), one more observation, exit. ``--sapiens-table`` leaves SAPIEN's table in place. Compare them side by
side in one call (whole processes, paired runs, median ratio)::

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

    from drem_maniskill.envs import rendering

    if args.sapiens_table:
        rendering.skip_brdf_lut = lambda scene, cameras: 0
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        env = gym.make(args.task, obs_mode="rgb")
    obs = env.unwrapped.get_obs()
    print(float(next(iter(obs["sensor_data"].values()))["rgb"].float().mean()))
    env.close()


if __name__ == "__main__":
    main()
