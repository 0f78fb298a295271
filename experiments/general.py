"""The general recipe on held-part insertion tasks: its reward, state SAC on it, and sparse and engineered beside.

Each task's reward is built with the general recipe (``recipe="default"``, even on a task with a recipe file of its
own) into ``<out>/build/<task>``; state-preset SAC then trains on it to 50,000 steps (``--seeds``) into
``<out>/<task>/drem/seed<S>``, and on ``sparse`` and ``engineered`` (``--baseline-seeds``) beside it, all through the
sweep, two at a time. Rerunning the same command resumes every build and run. Written to ``docs/results/general/``:
``<task>/examination.json`` (the build's measures, its time and recipe), ``<task>/build/`` (its checkpoint,
examination and recipe: where ``<out>`` lacks them, a rerun restores them instead of building again) and each run's
small files under ``<task>/<reward>/seed<S>/``; ``--table`` prints the table of ``docs/results.md`` from them.

    .venv/bin/python experiments/general.py --tasks SquarePegInHole-v1 DPegInHole-v1 --seeds 0 1
    .venv/bin/python experiments/general.py --tasks PegInHole-v1 --seeds 0 1 2 --baseline-seeds
    .venv/bin/python experiments/general.py --table
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from ablation import sac_cell  # experiments/ is the script's folder
from general_recipe import STATE_RUN, copy_run_files, drem_sac_configs, examination_measures, timed_build

RESULTS = Path("docs/results/general")
BASELINES = ("sparse", "engineered")


def build(task: str, out: Path) -> dict:
    """Build ``task``'s general-recipe reward (resuming) and write its examination summary; returns the summary."""
    from drem_maniskill.pipeline.recipe import GENERAL, load_recipe

    work = out / "build" / task
    checkpoint, seconds = timed_build(task, work, GENERAL, keep=RESULTS / task / "build")
    quality = json.loads((work / "quality.json").read_text())
    result = dict(task=task, recipe=load_recipe(task, "full", GENERAL).to_dict(), build_seconds=round(seconds),
                  checkpoint=str(checkpoint), **examination_measures(quality))
    dest = RESULTS / task / "examination.json"
    dest.parent.mkdir(parents=True, exist_ok=True)
    dest.write_text(json.dumps(result, indent=1) + "\n")
    return result


def sac_configs(tasks, out: Path, seeds, baseline_seeds, steps: int) -> list:
    """State-preset configs: each task's general reward per seed, then sparse and engineered per baseline seed."""
    from drem_maniskill.rl.sweep import trial_config

    drem = drem_sac_configs([(t, out / "build" / t / "drem.pt", out / t / "drem") for t in tasks], seeds, steps)
    return drem + [trial_config("state", t, r, s, steps, out, STATE_RUN) for t in tasks for r in BASELINES
                   for s in baseline_seeds]


def table(steps: int) -> str:
    """The general recipe's table (markdown) from ``docs/results/general``: each task's examination and its SAC."""
    lines = ["| task | build | value order | AUROC | expert end, held-out | floor beside / inserted | "
             "at the opening, 4 mm off / on the axis | "
             f"DREM: state SAC at {steps:,} steps, per seed | sparse | engineered |", "| --- " * 10 + "|"]
    for exam in sorted(RESULTS.glob("*/examination.json")):
        r, folder = json.loads(exam.read_text()), exam.parent
        ratios = [r.get(k) for k in ("floor_beside_over_inserted", "mouth_off_axis_over_on_axis")]
        lines.append(f"| {r['task']} | {r['build_seconds'] / 3600:.1f} h | {r['value_order_spearman']:.3f} | "
                     f"{r['final_reward_auroc']:.3f} | {r['expert_end_heldout']:.2f} | "
                     + "".join("n/a | " if x is None else f"{x:.2f} | " for x in ratios)
                     + " | ".join(sac_cell(folder / reward, steps) for reward in ("drem",) + BASELINES) + " |")
    return "\n".join(lines)


def main() -> None:
    """Build every task's general reward, then train SAC on it and on the baselines through the sweep."""
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--tasks", nargs="+", default=[])
    p.add_argument("--seeds", nargs="*", type=int, default=[0, 1, 2], help="state SAC seeds on the DREM reward")
    p.add_argument("--baseline-seeds", nargs="*", type=int, default=[0], help="seeds of sparse and engineered")
    p.add_argument("--steps", type=int, default=50_000)
    p.add_argument("--out", default="outputs/general")
    p.add_argument("--table", action="store_true", help="print the table of the committed results and stop")
    args = p.parse_args()
    if args.table:
        print(table(args.steps))
        return
    if not args.tasks:
        p.error("--tasks is required to build and train")
    out = Path(args.out)
    for task in args.tasks:
        result = build(task, out)
        print(json.dumps({k: result[k] for k in ("task", "value_order_spearman", "final_reward_auroc",
                                                 "build_seconds")}), flush=True)
    configs = sac_configs(args.tasks, out, args.seeds, args.baseline_seeds, args.steps)
    if configs:
        from drem_maniskill.rl.sweep import run_sweep

        run_sweep(configs, out)
        for c in configs:  # <out>/<task>/<reward>/seed<S> -> RESULTS/<task>/<reward>/seed<S>
            copy_run_files(Path(c.out), RESULTS / Path(c.out).relative_to(out))


if __name__ == "__main__":
    main()
