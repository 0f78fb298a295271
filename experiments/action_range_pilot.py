"""How the sampler's action range shapes the reward at a socket's mouth: the general recipe against a narrower range.

Backward sampling labels every child of a seed with the seed's depth plus one, however far its random action moved
it. Where the part moves freely (above the opening) the children of the general recipe's range (four times the
expert's step, at least ``min_action_scale``) spread several millimetres around the demo's path, all at one depth:
the tree itself teaches that a part off the axis at the opening is as far along as one on it. This pilot builds the
reward of ``task`` twice at a smaller scale of training (``ITERATIONS``), under the general recipe (its tree taken
from the full build of ``experiments/general.py``, ``<out>/build/<task>``) and with the range of one expert step
(``NARROW``), and reports for each the tree's spread at the opening (``tip_in_socket``, a measure the sampler never
reads) and the examination's measures, ``mouth_off_axis_over_on_axis`` among them, to
``docs/results/general/<task>/action_range_pilot.json``. Rerunning resumes both builds.

    .venv/bin/python experiments/action_range_pilot.py --task SquarePegInHole-v1
"""

from __future__ import annotations

import argparse
import json
import os
from pathlib import Path

import h5py
import numpy as np
from general_recipe import examination_measures  # experiments/ is the script's folder

RESULTS = Path("docs/results/general")
ITERATIONS = {"train": {"iterations": 5_000}}
# One expert step (not four), and a floor of 1 % of the controller's translation limit (not 5 %).
NARROW = {"sampler": {"expert_step_scale": 1.0, "min_action_scale": 0.01}}
PILOTS = {"general": (ITERATIONS,), "narrow": (NARROW, ITERATIONS)}


def spread_above_opening(tree: Path) -> list:
    """Per depth whose nodes' median tip height is 0-20 mm above the opening: the depth, that height, and the median
    and 90th-percentile distance of its nodes' tips from the socket's axis (mm)."""
    with h5py.File(tree, "r") as f:
        depth, tip = f["depth"][()], f["tip_in_socket"][()] * 1000
    rows = []
    for d in np.unique(depth):
        at = tip[depth == d]
        height = float(np.median(at[:, 2]))
        if 0 <= height <= 20 and len(at) > 1:
            off = np.hypot(at[:, 0], at[:, 1])
            rows.append(dict(depth=int(d), height_mm=round(height, 1), off_axis_mm_p50=round(float(np.median(off)), 2),
                             off_axis_mm_p90=round(float(np.percentile(off, 90)), 2)))
    return rows


def main() -> None:
    """Build both pilots (resuming) and write their measures."""
    from drem_maniskill.pipeline.build_reward import build_reward
    from drem_maniskill.pipeline.recipe import GENERAL_DEFAULTS, merge

    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--task", required=True)
    p.add_argument("--out", default="outputs/general")
    args = p.parse_args()
    out, task = Path(args.out), args.task
    summary = {}
    for name, parts in PILOTS.items():
        recipe = GENERAL_DEFAULTS
        for part in parts:
            recipe = merge(recipe, part)
        work = out / "action_range_pilot" / task / name
        work.mkdir(parents=True, exist_ok=True)
        if name == "general":  # the full build's demo and tree: only the training differs
            for entry in ("expert", "tree.h5"):
                if not (work / entry).exists():
                    src = out / "build" / task / entry
                    os.symlink(src.resolve(), work / entry, target_is_directory=src.is_dir())
        build_reward(task, scale="full", out=work, recipe=recipe)
        quality = json.loads((work / "quality.json").read_text())
        summary[name] = dict(recipe_changes=parts, spread_above_opening=spread_above_opening(work / "tree.h5"),
                             **examination_measures(quality))
        print(name, json.dumps({k: summary[name][k] for k in ("value_order_spearman", "mouth_off_axis_over_on_axis")}),
              flush=True)
    dest = RESULTS / task / "action_range_pilot.json"
    dest.parent.mkdir(parents=True, exist_ok=True)
    dest.write_text(json.dumps(summary, indent=1) + "\n")


if __name__ == "__main__":
    main()
