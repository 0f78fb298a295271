"""The examination's held positions at the opening, for rewards side by side (docs/experiment-log.md).

    python experiments/opening_holds.py --task SquarePegInHole-v1 \\
        docs/results/general_recipe/SquarePegInHole-v1/build/even_path_outward_twist_far_fine_slide_wander_long/drem.pt

Prints, per checkpoint, the mean reward over ``--seeds`` with the part held 10 and 4 mm above the opening, 4 mm above
it 1, 2 and 4 mm off its axis, pressed on the face 3 mm beside it, at the expert's insertion, and (``--tilts``) 4 mm
above it on the axis tilted 3 and 6 deg or turned 5 and 10 deg about its own axis. With ``--images``
(no checkpoint needed), how many of each camera's pixels change by more than 16 of 255 between the part held on the
axis and 1, 2 and 4 mm off it, at 128 px and shrunk to 64 px as the model reads them (seed 0).
"""

from __future__ import annotations

import argparse
import json

import numpy as np

HOLDS = ("10 mm above", "4 mm above", "4 mm above, 1 mm off", "4 mm above, 2 mm off", "4 mm above, 4 mm off",
         "pressed 3 mm beside")

# Name -> rotation vector (socket frame, deg) of the part held 4 mm above the opening on its axis.
TILTS = {"tilted 3 deg": (3, 0, 0), "tilted 6 deg": (6, 0, 0), "turned 5 deg": (0, 0, 5), "turned 10 deg": (0, 0, 10)}


def opening_holds(task: str, checkpoint: str, seeds, tilts: bool = False) -> dict:
    """``{hold: mean reward}`` for ``HOLDS`` and ``"inserted"`` (with ``tilts``, ``TILTS`` too) under ``checkpoint``
    on ``task``."""
    import gymnasium as gym

    import drem_maniskill  # noqa: F401  (registers the tasks)
    from drem_maniskill.evaluate.probes import hold_positions, hold_targets

    env = gym.make(task, obs_mode="state_dict", reward_mode="drem", drem_checkpoint=checkpoint)
    try:
        targets = hold_targets(env)
        positions = {name: targets[name] for name in HOLDS}
        turns = {}
        if tilts:
            positions.update({name: targets["4 mm above"] for name in TILTS})
            turns = {name: tuple(np.deg2rad(turn)) for name, turn in TILTS.items()}
        held = hold_positions(env, seeds, positions, turns=turns)
    finally:
        env.close()
    return {name: None if h["mean"] is None else round(h["mean"], 3) for name, h in held.items()}


def image_change(task: str, seed: int = 0, threshold: int = 16) -> dict:
    """``{hold: {"<camera> <size>px": pixels changed}}`` against the part held 4 mm above the opening on its axis."""
    import gymnasium as gym

    import drem_maniskill  # noqa: F401  (registers the tasks)
    from drem_maniskill.evaluate.probes import HOLD_STEPS, hold_targets
    from drem_maniskill.experts import rollout
    from drem_maniskill.experts.scripted import HoldPolicy
    from drem_maniskill.pipeline.dataset import resize_images

    env = gym.make(task, obs_mode="rgb", reward_mode="none")
    try:
        targets = hold_targets(env)
        images = {}
        for name in HOLDS[1:5]:
            rollout(env, HoldPolicy(env, targets[name]), seed, HOLD_STEPS)
            sensors = env.unwrapped.get_obs()["sensor_data"]
            images[name] = {c: sensors[c]["rgb"][:1].cpu().numpy() for c in sensors}
    finally:
        env.close()
    base = images.pop(HOLDS[1])
    out = {}
    for name, held in images.items():
        out[name] = {}
        for camera, image in held.items():
            for size in (image.shape[1], 64):
                diff = (resize_images(base[camera], size).float() - resize_images(image, size).float()).abs()
                out[name][f"{camera} {size}px"] = int((diff.amax(-1) > threshold).sum())
    return out


def main() -> None:
    """Print each checkpoint's holds as one JSON line."""
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--task", required=True)
    p.add_argument("--seeds", type=int, default=5, help="seeds 0 .. N-1")
    p.add_argument("--tilts", action="store_true", help="the tilted and turned holds too")
    p.add_argument("--images", action="store_true", help="the pixels that change off the axis, not the rewards")
    p.add_argument("checkpoints", nargs="*")
    args = p.parse_args()
    if args.images:
        print(json.dumps(image_change(args.task)), flush=True)
    for checkpoint in args.checkpoints:
        held = opening_holds(args.task, checkpoint, range(args.seeds), args.tilts)
        print(json.dumps(dict(checkpoint=checkpoint, **held)), flush=True)


if __name__ == "__main__":
    main()
