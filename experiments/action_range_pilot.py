"""Whether the tree makes the reward flat across a socket's mouth: the general recipe's action range against one expert
step, and its depths against travel labels.

Backward sampling labels every child of a seed with the seed's depth plus one, however far its random action moved it.
Where the part moves freely (above the opening) the children of the general recipe's range (four times the expert's
step, at least ``min_action_scale``) spread several millimetres around the demo's path, all at one depth, so the tree
may itself teach that a part off the axis at the opening is as far along as one on it. This pilot builds the reward of
``task`` at a smaller scale of training (``ITERATIONS``) five ways: under the general recipe (its tree taken from the
full build of ``experiments/general.py``, ``<out>/build/<task>``), with the range of one expert step (``NARROW``), and
on the general tree with travel labels (``TRAVEL``, ``TRAVEL_2``, ``TRAVEL_2_HALF_MARGIN``: a child labelled by how far
it moved from its seed, one or two labels a demo step), and reports for each the tree's spread at the opening
(``tip_in_socket``, a measure the sampler never reads) and the examination's measures, ``mouth_off_axis_over_on_axis``
among them; beside them, how well each camera's image tells the offset at all (``offset_readout``). Written to
``docs/results/general/<task>/action_range_pilot.json``. ``--full`` adds the narrow range at the recipe's own 20,000
iterations (travel labels at that scale, with SAC on them: ``experiments/travel_labels.py``); ``--only`` builds the
named ones (the rest are read where built). Rerunning resumes every build.

    .venv/bin/python experiments/action_range_pilot.py --task SquarePegInHole-v1
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import h5py
import numpy as np
from general_recipe import examination_measures, link_demo_and_tree  # experiments/ is the script's folder

RESULTS = Path("docs/results/general")
ITERATIONS = {"train": {"iterations": 5_000}}
# One expert step (not four), and a floor of 1 % of the controller's translation limit (not 5 %).
NARROW = {"sampler": {"expert_step_scale": 1.0, "min_action_scale": 0.01}}
TRAVEL = {"train": {"travel_labels": 1.0}}
# Two labels a demo step: a part 4 mm off the axis at the opening is then more than the loss's eps = 4 labels from one
# on it (1.5 mm steps on the square peg's demo), where the near pairs' band no longer allows them the same distance.
TRAVEL_2 = {"train": {"travel_labels": 2.0}}
# The same labels with half the far pairs' margin a label, so that no margin asks more than the cosine distance's range
# of 2 (labels reach about 80 on the square peg's tree): for far pairs, one label a step with eps = 2.
TRAVEL_2_HALF_MARGIN = {"train": {"travel_labels": 2.0, "beta1": 0.02}}
# Name -> (the recipe's changes, the build whose demo and tree it takes: None samples its own).
PILOTS = {"general": ((ITERATIONS,), "build/{task}"), "narrow": ((NARROW, ITERATIONS), None),
          "travel": ((TRAVEL, ITERATIONS), "build/{task}"), "travel_2": ((TRAVEL_2, ITERATIONS), "build/{task}"),
          "travel_2_half_margin": ((TRAVEL_2_HALF_MARGIN, ITERATIONS), "build/{task}")}
FULL = {"narrow_20k": ((NARROW,), "action_range_pilot/{task}/narrow")}


def spread_above_opening(tree: Path) -> list:
    """Per depth whose nodes' median tip height is 0-20 mm above the opening: the depth, that height, and the median
    and 90th-percentile distance of its nodes' tips from the socket's axis (mm)."""
    with h5py.File(tree, "r") as f:
        depth, tip = f["depth"][()], f["tip_in_socket"][()] * 1000
    rows = []
    for d, height in zip(np.unique(depth), _median_heights(depth, tip)):
        at = tip[depth == d]
        if 0 <= height <= 20 and len(at) > 1:
            off = np.hypot(at[:, 0], at[:, 1])
            rows.append(dict(depth=int(d), height_mm=round(height, 1), off_axis_mm_p50=round(float(np.median(off)), 2),
                             off_axis_mm_p90=round(float(np.percentile(off, 90)), 2)))
    return rows


def offset_readout(tree: Path, sizes=(32, 64, 128), ridge: float = 1.0) -> dict:
    """How well each camera's image at each size tells where the part is across the opening: a ridge regression from
    the pixels to the tip's offset from the axis, fitted on 800 nodes 0-20 mm above the opening and tested on the rest;
    per camera and size, the median error (mm), beside guessing the mean offset."""
    import torch
    import torch.nn.functional as F

    with h5py.File(tree, "r") as f:
        depth, tip = f["depth"][()], f["tip_in_socket"][()] * 1000
        heights = np.array(_median_heights(depth, tip))
        above = np.unique(depth)[(heights >= 0) & (heights <= 20)]
        idx = np.nonzero(np.isin(depth, above) & (np.hypot(tip[:, 0], tip[:, 1]) < 20))[0]  # not the outward lineages
        offset = tip[idx, :2]
        images = {c: torch.as_tensor(f[f"{c}_rgb"][idx]).permute(0, 3, 1, 2).float() / 255 for c in ("fixed", "wrist")}
    order = np.random.default_rng(0).permutation(len(idx))
    fit, test = order[:800], order[800:]
    miss = offset[test] - offset[fit].mean(0)
    out = dict(nodes=len(idx), guess_mean_mm=round(float(np.median(np.hypot(miss[:, 0], miss[:, 1]))), 2))
    for camera, x in images.items():
        for size in sizes:
            flat = F.interpolate(x, size=(size, size), mode="area").flatten(1).numpy()
            flat = flat - flat[fit].mean(0)
            kernel = flat[fit] @ flat[fit].T
            weights = np.linalg.solve(kernel + ridge * np.eye(len(fit)), offset[fit] - offset[fit].mean(0))
            guess = flat[test] @ flat[fit].T @ weights + offset[fit].mean(0)
            miss = guess - offset[test]
            out[f"{camera}_{size}px_mm"] = round(float(np.median(np.hypot(miss[:, 0], miss[:, 1]))), 2)
    return out


def _median_heights(depth: np.ndarray, tip: np.ndarray) -> list:
    """Each depth's median tip height above the opening (``tip``: the nodes' tips in the socket's frame, mm), depths
    ascending."""
    return [float(np.median(tip[depth == d, 2])) for d in np.unique(depth)]


def _measures(parts: tuple, tree_from, work: Path) -> dict:
    """A finished pilot's record: its recipe changes, the examination's measures, the tree's spread at the opening."""
    quality = json.loads((work / "quality.json").read_text())
    return dict(recipe_changes=parts, tree_from=tree_from, **examination_measures(quality),
                spread_above_opening=spread_above_opening(work / "tree.h5"))


def main() -> None:
    """Build the pilots (resuming) and write their measures."""
    from drem_maniskill.pipeline.build_reward import build_reward
    from drem_maniskill.pipeline.recipe import GENERAL_DEFAULTS, merge

    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--task", required=True)
    p.add_argument("--out", default="outputs/general")
    p.add_argument("--full", action="store_true", help="also the narrow range at 20,000 iterations")
    p.add_argument("--only", nargs="+", choices=[*PILOTS, *FULL],
                   help="build only these; the rest are read where built")
    args = p.parse_args()
    out, task = Path(args.out), args.task
    summary = {}
    for name, (parts, tree_from) in {**PILOTS, **(FULL if args.full or args.only else {})}.items():
        recipe = GENERAL_DEFAULTS
        for part in parts:
            recipe = merge(recipe, part)
        work = out / "action_range_pilot" / task / name
        if args.only and name not in args.only:
            if (work / "quality.json").is_file():
                summary[name] = _measures(parts, tree_from, work)
            continue
        work.mkdir(parents=True, exist_ok=True)
        if tree_from:
            source = out / tree_from.format(task=task)
            if not (source / "tree.h5").exists():
                raise SystemExit(f"{name} trains on the tree in {source}, which has none: build it first")
            link_demo_and_tree(source, work)
        build_reward(task, scale="full", out=work, recipe=recipe)
        summary[name] = _measures(parts, tree_from, work)
        print(name, json.dumps({k: summary[name][k] for k in ("value_order_spearman", "mouth_off_axis_over_on_axis")}),
              flush=True)
    summary["offset_readout"] = offset_readout(out / "build" / task / "tree.h5")
    dest = RESULTS / task / "action_range_pilot.json"
    dest.parent.mkdir(parents=True, exist_ok=True)
    dest.write_text(json.dumps(summary, indent=1) + "\n")


if __name__ == "__main__":
    main()
