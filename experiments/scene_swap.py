"""Does a reward read the task or the robot? The examination's scene swap on rewards built before it had one.

For each ``TASK=CHECKPOINT``: the expert on held-out seeds, and at each successful end ``R`` with the robot there and
every other body back where the episode started, and the other way round (``pipeline.scene_swap.scene_swap``). Writes
the ratios and the per-episode rows to ``--out`` (JSON), one entry per checkpoint, and prints a line each.

    .venv/bin/python experiments/scene_swap.py PushCube-v1=outputs/general_recipe/PushCube-v1/five_trees/drem.pt \\
        PegInHole-v1=rewards/PegInHole-v1/drem.pt --out docs/results/scene_swap.json
"""

from __future__ import annotations

import argparse
import json
import os
from pathlib import Path


def measure(task: str, checkpoint: str, seeds) -> dict:
    """The scene-swap ratios of ``checkpoint`` on ``task`` over the expert's successful episodes on ``seeds``."""
    from drem_maniskill.evaluate.examine import _make_env, examination_episode
    from drem_maniskill.evaluate.scene_swap import scene_swap, swap_ratios
    from drem_maniskill.utils.progress import progress_bar

    env = _make_env(task, checkpoint, None)
    rows = []
    try:
        for seed in progress_bar(seeds, desc=f"scene swap: {task}", unit="episode"):
            if examination_episode(env, "expert", seed)["success"]:
                rows.append(dict(seed=seed, **scene_swap(env, seed)))
    finally:
        env.close()
    return dict(task=task, checkpoint=checkpoint, episodes=len(rows), **swap_ratios(rows), rows=rows)


def main() -> None:
    """Measure every ``TASK=CHECKPOINT`` and write them to ``--out`` (kept entries of other checkpoints stay)."""
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("rewards", nargs="+", metavar="TASK=CHECKPOINT")
    p.add_argument("--seeds", type=int, default=20, help="held-out seeds 0 .. N-1, as the examination's")
    p.add_argument("--out", default="docs/results/scene_swap.json")
    args = p.parse_args()
    out = Path(args.out)
    results = json.loads(out.read_text()) if out.is_file() else {}
    for item in args.rewards:
        task, _, checkpoint = item.partition("=")
        if not checkpoint:
            p.error(f"{item!r}: write TASK=CHECKPOINT")
        r = measure(task, checkpoint, range(args.seeds))
        results[checkpoint] = r
        print(f"{task} {checkpoint}: robot only / expert {r['robot_only_over_expert']:.3f}, "
              f"objects only / expert {r['objects_only_over_expert']:.3f} ({r['episodes']} episodes)", flush=True)
        tmp = out.with_name(out.name + ".tmp")
        tmp.write_text(json.dumps(results, indent=1) + "\n")
        os.replace(tmp, out)


if __name__ == "__main__":
    main()
