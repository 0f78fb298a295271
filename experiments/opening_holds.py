"""The examination's held positions at the opening, for rewards side by side (docs/experiment-log.md).

    python experiments/opening_holds.py --task SquarePegInHole-v1 \\
        docs/results/general_recipe/SquarePegInHole-v1/build/even_path_outward_twist_far_fine_slide_wander_long/drem.pt

Prints, per checkpoint, the mean reward over ``--seeds`` with the part held 10 and 4 mm above the opening, 4 mm above
it 1, 2 and 4 mm off its axis, pressed on the face 3 mm beside it, and at the expert's insertion.
"""

from __future__ import annotations

import argparse
import json

HOLDS = ("10 mm above", "4 mm above", "4 mm above, 1 mm off", "4 mm above, 2 mm off", "4 mm above, 4 mm off",
         "pressed 3 mm beside")


def opening_holds(task: str, checkpoint: str, seeds) -> dict:
    """``{hold: mean reward}`` for ``HOLDS`` and ``"inserted"`` under ``checkpoint`` on ``task``."""
    import gymnasium as gym

    import drem_maniskill  # noqa: F401  (registers the tasks)
    from drem_maniskill.evaluate.probes import hold_positions, hold_targets

    env = gym.make(task, obs_mode="state_dict", reward_mode="drem", drem_checkpoint=checkpoint)
    try:
        targets = hold_targets(env)
        held = hold_positions(env, seeds, {name: targets[name] for name in HOLDS})
    finally:
        env.close()
    return {name: None if h["mean"] is None else round(h["mean"], 3) for name, h in held.items()}


def main() -> None:
    """Print each checkpoint's holds as one JSON line."""
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--task", required=True)
    p.add_argument("--seeds", type=int, default=5, help="seeds 0 .. N-1")
    p.add_argument("checkpoints", nargs="+")
    args = p.parse_args()
    for checkpoint in args.checkpoints:
        print(json.dumps(dict(checkpoint=checkpoint, **opening_holds(args.task, checkpoint, range(args.seeds)))),
              flush=True)


if __name__ == "__main__":
    main()
