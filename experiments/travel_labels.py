"""The general recipe with travel labels, on a general-recipe build's tree, then state SAC on the reward it gives.

The general recipe labels every child of a seed with the seed's depth plus one, however far its random action carried
the part; with ``[train] travel_labels`` a child is labelled its seed's depth plus how far its action moved the hand, in
the demo's median steps (``drem_maniskill.pipeline.dataset.travel_labels``), so that a part that wandered off the demo's
path sits farther from the goal than one beside it. This trains that reward at the recipe's own scale on the demo and
tree of ``experiments/general.py``'s build (``<out>/build/<task>``, linked: only the training differs; where there is
none, recorded and sampled here as that build would), in ``<out>/travel/<task>``, examines it, and trains state SAC on
it through the sweep into ``<out>/travel/<task>/sac``. The examination's measures and each run's small files go to
``docs/results/general/<task>/travel/``; ``--scale k`` (labels per demo step, 1 by default) works in ``travel_<k>``.
Rerunning the command resumes every stage.

    .venv/bin/python experiments/travel_labels.py --task SquarePegInHole-v1 --seeds 0 1
"""

from __future__ import annotations

import argparse
import json
import os
from pathlib import Path

from general_recipe import examination_measures, link_demo_and_tree, sac_on_reward  # experiments/ is the folder

RESULTS = Path("docs/results/general")


def main() -> None:
    """Train and examine the travel-labelled reward on the build's tree, then SAC on it through the sweep."""
    from drem_maniskill.pipeline.build_reward import build_reward
    from drem_maniskill.pipeline.recipe import GENERAL_DEFAULTS, merge

    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--task", required=True)
    p.add_argument("--seeds", nargs="*", type=int, default=[0, 1], help="state SAC seeds on the new reward")
    p.add_argument("--steps", type=int, default=50_000)
    p.add_argument("--scale", type=float, default=1.0, help="labels per demo median step of travel")
    p.add_argument("--out", default="outputs/general")
    args = p.parse_args()
    out, task = Path(args.out), args.task
    name = "travel" if args.scale == 1 else f"travel_{args.scale:g}"
    travel = {"train": {"travel_labels": args.scale}}
    work, build = out / name / task, out / "build" / task
    work.mkdir(parents=True, exist_ok=True)
    link_demo_and_tree(build, work)
    checkpoint = build_reward(task, scale="full", out=work, recipe=merge(GENERAL_DEFAULTS, travel))
    quality = json.loads((work / "quality.json").read_text())
    dest = RESULTS / task / name
    dest.mkdir(parents=True, exist_ok=True)
    tree = (work / "tree.h5").resolve()
    summary = dict(task=task, recipe_changes=travel, tree=os.path.relpath(tree, out.resolve()),
                   **examination_measures(quality))
    (dest / "examination.json").write_text(json.dumps(summary, indent=1) + "\n")
    print(json.dumps({k: summary[k] for k in ("value_order_spearman", "mouth_off_axis_over_on_axis")}), flush=True)
    sac_on_reward(task, checkpoint, work / "sac", args.seeds, args.steps, out, dest)


if __name__ == "__main__":
    main()
