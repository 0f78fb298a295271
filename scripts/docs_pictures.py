"""Write the camera pictures shown in docs/tasks.md: docs/images/<task>_<camera>.png.

Each picture is the camera's 128x128 RGB observation, halfway through an expert episode
(seed 0), in the default lean render style; `--style full` adds the full-style pictures.
Run: .venv/bin/python scripts/docs_pictures.py
"""

import argparse
from pathlib import Path

import gymnasium as gym
import matplotlib.pyplot as plt
import numpy as np

from drem_maniskill.envs import TASKS
from drem_maniskill.experts import get_policy


def main() -> None:
    """Render each camera of each task mid-way through an expert episode."""
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--out", default="docs/images")
    parser.add_argument("--style", nargs="+", default=["lean", "full"])
    parser.add_argument("--tasks", nargs="+", default=list(TASKS))
    args = parser.parse_args()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    for task in args.tasks:
        for style in args.style:
            env = gym.make(task, obs_mode="rgb", render_style=style)
            policy = get_policy("expert", env)
            obs, _ = env.reset(seed=0)
            for _ in range(6):
                obs, *_ = env.step(policy(obs))
            suffix = "" if style == "lean" else "_full"
            for cam in ("fixed_camera", "wrist_camera"):
                img = obs["sensor_data"][cam]["rgb"][0].numpy()
                plt.imsave(out / f"{task}_{cam}{suffix}.png", np.ascontiguousarray(img))
                print("wrote", out / f"{task}_{cam}{suffix}.png")
            env.close()


if __name__ == "__main__":
    main()
