"""Scene-swap negatives on a built forest: do they make the reward read the task's objects rather than the robot?

Takes a general-recipe build (``experiments/general_recipe.py``, e.g. ``five_trees``), writes the scene-swap
negatives of each demo episode (``pipeline.scene_swap.swap_negatives``), trains the same recipe's model on the same
trees with them for each ``--iterations``, examines it, and measures what it pays its own negatives (all of them, and
those with the robot at the goal). Every stage is skipped when its output exists. The summary goes to
``docs/results/general_recipe/<task>/<variant>_scene_swap.json``.

    .venv/bin/python experiments/swap_negatives.py --task PushCube-v1 --variant five_trees --iterations 2000 6000
"""

from __future__ import annotations

import argparse
import json
import os
from pathlib import Path

import numpy as np


def paid_on(checkpoint: str, files) -> dict:
    """The mean ``R`` the reward pays the negatives in ``files``: all, and those with the robot at the goal."""
    import h5py

    from drem_maniskill.drem.reward import DREMReward
    from drem_maniskill.pipeline.negatives import paid_on_negatives

    reward = DREMReward.from_checkpoint(checkpoint)
    paid, robot_depth = [], []
    for path in files:
        paid.append(paid_on_negatives(reward, path))
        with h5py.File(path, "r") as f:
            robot_depth.append(f["step"][()])
    paid, robot_depth = np.concatenate(paid), np.concatenate(robot_depth)
    return dict(negatives=len(paid), all=float(paid.mean()), robot_at_goal=float(paid[robot_depth == 0].mean()))


def main() -> None:
    """Negatives, training, examination and the summary for every ``--iterations``."""
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--task", required=True)
    p.add_argument("--variant", default="five_trees", help="the general-recipe build whose demo and trees are used")
    p.add_argument("--iterations", type=int, nargs="+", default=[2000])
    p.add_argument("--lag", type=int, default=4)
    p.add_argument("--builds", default="outputs/general_recipe")
    p.add_argument("--out", default="outputs/swap_negatives")
    args = p.parse_args()
    from general_recipe import RESULTS, recipe

    from drem_maniskill.evaluate.examine import examine
    from drem_maniskill.pipeline.dataset import dataset_modalities
    from drem_maniskill.pipeline.recipe import load_recipe
    from drem_maniskill.pipeline.scene_swap import swap_negatives
    from drem_maniskill.pipeline.train_reward import train_reward

    src, out = Path(args.builds) / args.task / args.variant, Path(args.out) / args.task / args.variant
    r = load_recipe(args.task, "full", recipe(args.variant))
    trees = [src / "tree.h5", *(src / f"tree_{k}.h5" for k in range(1, r.demo["trees"]))]
    out.mkdir(parents=True, exist_ok=True)
    negatives = [str(out / f"negatives_{k}.h5") for k in range(len(trees))]
    for k, path in enumerate(negatives):
        if not Path(path).exists():
            swap_negatives(str(src / "expert" / "expert.h5"), path, episode=k, lag=args.lag)
    runs = []
    for iterations in args.iterations:
        work = out / f"iterations_{iterations}"
        checkpoint = work / "reward" / "drem.pt"
        if not checkpoint.exists():
            modalities = r.train["model"].get("modalities") or dataset_modalities(str(trees[0]))
            config = r.train_config(modalities=modalities, iterations=iterations)
            train_reward(str(trees[0]), str(checkpoint.parent), config, negatives=negatives,
                         trees=[str(t) for t in trees[1:]])
        quality_path = work / "examination" / "quality.json"
        if not quality_path.exists():
            examine(args.task, str(checkpoint), seeds=r.exam_seeds(), out_dir=str(quality_path.parent))
        q = json.loads(quality_path.read_text())
        runs.append(dict(iterations=iterations, paid_on_own_negatives=paid_on(str(checkpoint), negatives),
                         **{k: q[k] for k in ("value_order_spearman", "final_reward_auroc",
                                              "final_reward_auroc_expert_noisy", "random_mean_reward",
                                              "robot_only_over_expert", "objects_only_over_expert")}))
        print(json.dumps(runs[-1]), flush=True)
    dest = RESULTS / args.task / f"{args.variant}_scene_swap.json"
    # What the build itself, trained without them, pays the same negatives.
    without = paid_on(str(src / "drem.pt"), negatives)
    summary = dict(task=args.task, built_on=args.variant, lag=args.lag, paid_without_them=without, runs=runs)
    tmp = dest.with_name(dest.name + ".tmp")
    tmp.write_text(json.dumps(summary, indent=1) + "\n")
    os.replace(tmp, dest)


if __name__ == "__main__":
    main()
