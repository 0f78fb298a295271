"""The README's main job: ``build_reward`` at a small scale on every task of ``envs.TASKS``, with plots.

For each task: its recipe's expert demo (the committed one, else one recorded with the recipe's ``[demo]``
settings), drawn; then ``build_reward`` at the recipe's ``demo`` scale (sample the progress tree, train the
progress model, examine the learned reward with the paper's four scripted policies on held-out seeds), working in
``<out>/<task>/`` and resuming there when run again. It writes, per task:

* ``<task>/drem.pt``: the reward checkpoint, usable as
  ``gym.make(task, reward_mode="drem", drem_checkpoint=...)``;
* ``<task>/examination.png`` and ``quality.json``: reward against time per policy
  and the model-card figures (value-order Spearman, AUROC, Random mean, contact-loss drop);
* ``<task>/fixed_camera_strip.png`` and ``<task>/wrist_camera_strip.png``: frames along the
  demo's first episode, left to right;
* ``<task>/ft.png``: the wrist force/torque history at physics rate (100 Hz), one window of 8
  readings per control step, with the insertion depth beneath;
* ``summary.json``: the demo's success and episode lengths per task, and the examination's measures.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Sequence

import h5py
import numpy as np

import gymnasium as gym

from drem_maniskill.envs import TASKS
from drem_maniskill.pipeline.build_reward import build_reward, demo_stage
from drem_maniskill.pipeline.recipe import load_recipe
from drem_maniskill.utils.atomic import atomic_path, write_json

MEASURES = ("value_order_spearman", "final_reward_auroc", "random_mean_reward", "search_fail_contact_loss")
CAMERAS = ("fixed_camera", "wrist_camera")


def image_strip(frames: np.ndarray, count: int = 8) -> np.ndarray:
    """Concatenate ``count`` evenly spaced frames ``[T, H, W, 3]`` side by side."""
    idx = np.linspace(0, len(frames) - 1, num=min(count, len(frames))).round().astype(int)
    return np.concatenate([frames[i] for i in idx], axis=1)


def plot_ft(ft: np.ndarray, depth: np.ndarray, sim_dt: float, control_dt: float, path: Path, title: str) -> None:
    """Plot F/T windows ``[T, H, 6]`` (newest last) against time, with depth ``[T]`` below."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    steps, history, _ = ft.shape
    fig, axes = plt.subplots(3, 1, figsize=(8, 7), sharex=True)
    names = ["x", "y", "z"]
    for k in range(steps):
        t = k * control_dt - (history - 1 - np.arange(history)) * sim_dt
        for j in range(3):
            axes[0].plot(t, ft[k, :, j], color=f"C{j}", lw=1, label=f"F{names[j]}" if k == 0 else None)
            axes[1].plot(t, ft[k, :, 3 + j], color=f"C{j}", lw=1, label=f"T{names[j]}" if k == 0 else None)
    axes[0].set_ylabel("force [N]")
    axes[1].set_ylabel("torque [N m]")
    axes[2].plot(np.arange(steps) * control_dt, depth * 1000, "k.-")
    axes[2].set_ylabel("insertion depth [mm]")
    axes[2].set_xlabel("time [s] (each line: the 8 readings at 100 Hz in one observation)")
    for ax in axes[:2]:
        ax.legend(loc="upper left", ncol=3, fontsize=8)
    fig.suptitle(title)
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=90, format="png")
    plt.close(fig)


def _save_png(img: np.ndarray, path: Path) -> None:
    import matplotlib.pyplot as plt

    with atomic_path(path) as tmp:
        plt.imsave(tmp, img, format="png")


def draw_demo(task: str, expert: Path, folder: Path) -> dict:
    """Draw the first episode of the demo ``expert`` into ``folder``; returns its success, lengths and plots."""
    episodes = json.loads(expert.with_suffix(".json").read_text())["episodes"]
    env = gym.make(task)
    sim_dt, control_dt = env.unwrapped.sim_timestep, env.unwrapped.control_timestep
    env.close()
    plots = []
    with h5py.File(expert, "r") as f:
        obs = f["traj_0/obs"]
        for cam in CAMERAS:
            if f"sensor_data/{cam}/rgb" in obs:
                plots.append(folder / f"{cam}_strip.png")
                _save_png(image_strip(obs[f"sensor_data/{cam}/rgb"][()]), plots[-1])
        if "extra/ft" in obs:
            tcp = obs["extra/tcp_pose"][()]
            # Depth from the TCP height, relative to the first step (no privileged state in rgb obs).
            depth = np.maximum(0.0, tcp[0, 2] - tcp[:, 2])
            plots.append(folder / "ft.png")
            plot_ft(obs["extra/ft"][()], depth, sim_dt, control_dt, plots[-1],
                    f"{task}: expert, seed {episodes[0]['episode_seed']}")
    return dict(success=[bool(e["success"]) for e in episodes], lengths=[int(e["elapsed_steps"]) for e in episodes],
                trajectory=str(expert), plots=[str(p) for p in plots])


def run_demo(out: str = "outputs/demo", tasks: Sequence[str] = TASKS, scale: str = "demo", drem: bool = True) -> dict:
    """Draw each task's expert demo and (``drem``) build its reward with ``build_reward`` at ``scale``.

    The settings are each task's recipe (``tasks/<id>/recipe.toml``) at ``scale`` (``demo``: minutes per task;
    ``tiny``: for tests); each task works in ``<out>/<task>/``.
    """
    recipes = {task: load_recipe(task, scale) for task in tasks}
    root = Path(out)
    summary = {}
    for task in tasks:
        folder = root / task
        folder.mkdir(parents=True, exist_ok=True)
        summary[task] = draw_demo(task, demo_stage(recipes[task], folder), folder)
        if not drem:
            continue
        checkpoint = build_reward(task, scale=scale, out=folder)
        quality = json.loads((folder / "quality.json").read_text())
        # Where the examination plot's Direct Success curve ends: a working reward pays about 1 at the goal.
        finals = [run[-1] for run in quality["curves"]["direct_success"] if len(run)]
        summary[task].update(
            tree=str(folder / "tree.h5"), checkpoint=str(checkpoint),
            quality={**{k: quality[k] for k in MEASURES},
                     "direct_success_final_reward": float(np.mean(finals)) if finals else None},
        )
        summary[task]["plots"].append(str(folder / "examination.png"))
    write_json(root / "summary.json", summary)
    return summary
