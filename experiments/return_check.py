"""Whether a tree's children near the goal are one step from their seed the other way round: each child's action undone.

Backward sampling labels a child one step farther from the goal than its seed because the random action that made it,
undone, would bring it back. Where the part moves freely that holds; where it is in contact (inside the hole, on the
socket's edge) undoing the action need not bring it back. For every seed of a built tree at depths ``--depths``,
``--children`` fresh children are drawn in the range the loop drew them in, each action is applied from the restored
seed and then undone, and the part's tip is compared with the seed's (``tip_in_socket``, a measure the sampler never
reads). Reported per depth: the return error's median and 90th percentile, by how far the child's tip was off the
socket's axis. Written to ``docs/results/general/<task>/return_check.json``.

    .venv/bin/python experiments/return_check.py --task SquarePegInHole-v1   # outputs/general/build/<task>/tree.h5
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import h5py
import numpy as np
import torch

import drem_maniskill  # noqa: F401  (registers the tasks)
from drem_maniskill.pipeline.tree.backward import action_scale_at
from drem_maniskill.pipeline.tree.child_sampler import ChildSampler
from drem_maniskill.pipeline.tree.config import SamplerConfig
from drem_maniskill.utils.atomic import write_json
from drem_maniskill.utils.state import broadcast_state

RESULTS = Path("docs/results/general")
OFF_AXIS_MM = ((0, 2), (2, 5), (5, 1e9))


def check(tree: str, depths: range, children: int, seed: int = 0) -> list:
    """One row per child: its depth, the range, its tip's height and distance off the axis, and the return error."""
    with h5py.File(tree, "r") as f:
        header = json.loads(f.attrs["header"])
        config = SamplerConfig.from_dict(header["config"])
        expert_ee = f["expert/ee_state"][()]
        seeds = {d: f[f"seeds/depth_{d}/state"][()] for d in depths if f"seeds/depth_{d}" in f}
    sampler = ChildSampler(header["env_id"], {}, header["episode_seed"], images=False)
    rng = np.random.default_rng(seed)
    rows = []
    try:
        for depth, states in seeds.items():
            scale = action_scale_at(depth, expert_ee, config, sampler.translation_limit)
            for flat in states:
                state = broadcast_state(sampler.adapter.unflatten(flat), sampler.n)
                sampler.adapter.set_state(state)
                seed_tip = sampler.adapter.tip_in_socket()[0].cpu().numpy()
                seed_mm = [round(float(x) * 1000, 2) for x in seed_tip]
                for action in sampler.random_actions(rng, children, scale):
                    a = torch.as_tensor(action[None], dtype=torch.float32)
                    sampler.adapter.set_state(state)
                    sampler.env.step(a)
                    tip = sampler.adapter.tip_in_socket()[0].cpu().numpy()
                    sampler.env.step(-a)
                    back = sampler.adapter.tip_in_socket()[0].cpu().numpy()
                    rows.append(dict(depth=depth, scale=scale, seed_tip_mm=seed_mm,
                                     off_axis_mm=float(np.linalg.norm(tip[:2]) * 1000),
                                     height_mm=float(tip[2] * 1000),
                                     return_error_mm=float(np.linalg.norm(back - seed_tip) * 1000)))
    finally:
        sampler.close()
    return rows


def summary(rows: list) -> list:
    """Per depth: the seed's tip, the range, and the return error (median, 90th percentile) by distance off the axis."""
    out = []
    for depth in sorted({r["depth"] for r in rows}):
        at = [r for r in rows if r["depth"] == depth]
        errors = np.array([r["return_error_mm"] for r in at])
        off = np.array([r["off_axis_mm"] for r in at])
        by_off = {}
        for lo, hi in OFF_AXIS_MM:
            m = (off >= lo) & (off < hi)
            by_off[f"{lo}-{hi if hi < 1e9 else 'up'} mm off"] = (
                dict(children=int(m.sum()), median=round(float(np.median(errors[m])), 3)) if m.any() else None)
        out.append(dict(depth=depth, seed_tip_mm=at[0]["seed_tip_mm"], scale=round(at[0]["scale"], 4),
                        median_mm=round(float(np.median(errors)), 3),
                        p90_mm=round(float(np.percentile(errors, 90)), 3), by_off_axis=by_off))
    return out


def main() -> None:
    """Check the tree, print the summary and write it."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--task", required=True)
    parser.add_argument("--tree", help="a built tree.h5 of the task (default: experiments/general.py's build)")
    parser.add_argument("--depths", type=int, nargs=2, default=(10, 26), help="first and last-plus-one depth")
    parser.add_argument("--children", type=int, default=64, help="children per seed")
    args = parser.parse_args()
    args.tree = args.tree or f"outputs/general/build/{args.task}/tree.h5"
    rows = check(args.tree, range(*args.depths), args.children)
    table = summary(rows)
    for row in table:
        print(json.dumps(row))
    write_json(RESULTS / args.task / "return_check.json",
               dict(task=args.task, tree=args.tree, depths=list(args.depths), children=args.children, summary=table))


if __name__ == "__main__":
    main()
