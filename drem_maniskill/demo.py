"""The README's main job: the whole DREM chain at a small scale, with plots, on every task of ``envs.TASKS``.

For each task: record expert episodes with ``RecordEpisode`` (ManiSkill's .h5/.json), build a
task progress tree by backward sampling from the first episode, train the progress model, and
examine the learned reward with the paper's four scripted policies on held-out seeds. It writes,
per task:

* ``<task>/reward/drem.pt``: the reward checkpoint, usable as
  ``gym.make(task, reward_mode="drem", drem_checkpoint=...)``;
* ``<task>/examination/examination.png`` and ``quality.json``: reward against time per policy
  and the model-card figures (value-order Spearman, AUROC, Random mean, contact-loss drop);

* ``<task>/fixed_camera_strip.png`` and ``<task>/wrist_camera_strip.png``: frames along the
  episode, left to right;
* ``<task>/ft.png``: the wrist force/torque history at physics rate (100 Hz), one window of 8
  readings per control step, with the insertion depth beneath;
* ``summary.json``: success and episode lengths per task.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Sequence

import h5py
import numpy as np

import gymnasium as gym

from drem_maniskill.envs import TASKS
from drem_maniskill.experts import record_expert
from drem_maniskill.pipeline import backward_sample
from drem_maniskill.pipeline.examine import examine
from drem_maniskill.pipeline.recipe import load_recipe
from drem_maniskill.pipeline.train_reward import train_reward


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
    tmp = path.with_suffix(".tmp.png")
    fig.savefig(tmp, dpi=90)
    plt.close(fig)
    os.replace(tmp, path)


def _save_png(img: np.ndarray, path: Path) -> None:
    import matplotlib.pyplot as plt

    tmp = path.with_suffix(".tmp.png")
    plt.imsave(tmp, img)
    os.replace(tmp, path)


def run_demo(out: str = "outputs/demo", tasks: Sequence[str] = TASKS, episodes: int = 2, seed: int = 0,
             scale: str = "demo", drem: bool = True) -> dict:
    """Record expert episodes per task, draw them, and (``drem``) run the DREM chain on them.

    The chain's settings are each task's recipe (``tasks/<id>/recipe.toml``) at ``scale`` (``demo``: minutes
    per task; ``tiny``: for tests); the expert episodes are the demo's own, recorded from ``seed``.
    """
    recipes = {task: load_recipe(task, scale) for task in tasks} if drem else {}
    root = Path(out)
    summary = {}
    for task in tasks:
        folder = root / task
        result = record_expert(task, str(folder), seeds=range(seed, seed + episodes), obs_mode="rgb")
        env = gym.make(task)
        sim_dt, control_dt = env.unwrapped.sim_timestep, env.unwrapped.control_timestep
        env.close()
        with h5py.File(result.h5_path, "r") as f:
            traj = f["traj_0"]
            for cam in ("fixed_camera", "wrist_camera"):
                _save_png(image_strip(traj[f"obs/sensor_data/{cam}/rgb"][()]), folder / f"{cam}_strip.png")
            ft = traj["obs/extra/ft"][()]
            tcp = traj["obs/extra/tcp_pose"][()]
        # Depth from the TCP height, relative to the first step (no privileged state in rgb obs).
        depth = np.maximum(0.0, tcp[0, 2] - tcp[:, 2])
        plot_ft(ft, depth, sim_dt, control_dt, folder / "ft.png", f"{task}: expert, seed {seed}")
        summary[task] = dict(
            success=result.success, lengths=result.lengths, trajectory=result.h5_path,
            plots=[str(folder / n) for n in ("fixed_camera_strip.png", "wrist_camera_strip.png", "ft.png")],
        )
        if not drem:
            continue
        recipe = recipes[task]
        tree = backward_sample(result.h5_path, str(folder / "tree.h5"), recipe.sampler_config(seed=seed))
        checkpoint = train_reward(tree, str(folder / "reward"), recipe.train_config())
        # Held-out seeds: clear of the recorded ones.
        exam_seeds = range(seed + 1000, seed + 1000 + recipe.examine["episodes"])
        quality = examine(task, checkpoint, seeds=exam_seeds, out_dir=str(folder / "examination"))
        summary[task].update(
            tree=tree, checkpoint=checkpoint,
            quality={k: quality[k] for k in ("value_order_spearman", "final_reward_auroc", "random_mean_reward",
                                             "search_fail_contact_loss")},
        )
        # Where the examination plot's Direct Success curve ends: a working reward pays about 1 at the goal.
        finals = [run[-1] for run in quality["curves"]["direct_success"] if len(run)]
        summary[task]["quality"]["direct_success_final_reward"] = float(np.mean(finals)) if finals else None
        summary[task]["plots"].append(str(folder / "examination" / "examination.png"))
    tmp = root / ".summary.json.tmp"
    tmp.write_text(json.dumps(summary, indent=2))
    os.replace(tmp, root / "summary.json")
    return summary
