"""What teaches in a task's DREM recipe: the paper's recipe, then one shipped ingredient added at a time.

Variants, each the one before plus one thing (all built from the task's own ``tasks/<id>/recipe.toml``):

    paper         one demo at the expert's own speed, the paper's fixed action range, no extra phase
    expert_step   + random actions scaled to the expert's step at each depth (``expert_step_scale``)
    slowed_demo   + the recipe's slowed demo (the committed ``expert.h5``)
    outward       + the recipe's outward lineages past the start region
    rounds        + three policy rounds of hard negatives
    phases        + the recipe's other sampler phases (tasks whose recipe has them)
    shipped       the recipe as written, without rounds (the shipped checkpoints' recipe)

At ``--scale full`` every variant samples M = 500 children and trains 20,000 iterations (the paper's); at
``pilot`` M = 100 and 2,000 iterations; at ``pilot_long`` M = 100 and 20,000 iterations (which of the two the
full scale needs). Each (task, variant) builds with ``build_reward`` into
``<out>/<scale>/<task>/<variant>/`` and is then trained on with state-preset SAC through the sweep
(``rl.sweep.run_sweep``), two trials at a time, into ``<out>/<scale>/sac/<task>/<variant>/seed<S>``. Rerunning
the same command resumes every build and run. The examination's measures go to
``docs/results/ablation/<scale>/<task>/<variant>.json`` and each run's ``config.json``, ``eval.csv`` and
``reward_checkpoint.json`` beside it, under ``<variant>/seed<S>/``.

    .venv/bin/python experiments/ablation.py --tasks PegInHole-v1 USBInsertion-v1 --variants shipped paper \
        --scale pilot --seeds 0
    .venv/bin/python experiments/ablation.py --table    # the table of docs/results/ablation, for docs/results.md
"""

from __future__ import annotations

import argparse
import json
import multiprocessing
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

# experiments/ is the script's folder
from general_recipe import copy_run_files, drem_sac_configs, examination_measures, timed_build

ORDER = ("paper", "expert_step", "slowed_demo", "outward", "rounds", "phases", "shipped")
SCALES = {"pilot": dict(num_children=100, iterations=2000), "pilot_long": dict(num_children=100, iterations=20000),
          "full": dict(num_children=500, iterations=20000)}
THREE_ROUNDS = {"rounds": 3, "sac_steps": 10000, "episodes": 20, "iterations": 1000}
RESULTS = Path("docs/results/ablation")


def shipped(task: str) -> dict:
    """The task's recipe file as a dict (without its scales)."""
    from drem_maniskill.pipeline.recipe import read_toml, recipe_path

    raw = read_toml(recipe_path(task), task)
    raw.pop("scales", None)
    return raw


def variant_recipe(task: str, variant: str, scale: str) -> dict:
    """The recipe dict of ``variant`` on ``task`` at ``scale``."""
    s = shipped(task)
    size = SCALES[scale]
    phases = dict(s.get("sampler", {}).get("phases", {}))
    outward = {"outward": phases.pop("outward")} if "outward" in phases else {}
    train = {"iterations": size["iterations"], "pairs_per_batch": 16, "threads": 1,
             "model": {"modalities": ["fixed", "wrist", "ft"], "image_size": 64}}
    common = {"examine": {"first_seed": 0, "episodes": 20}, "calibrate": {"enabled": False},
              "image_twin": {"enabled": False}}
    if variant == "shipped":
        r = {k: v for k, v in s.items() if k not in ("image_twin", "calibrate", "rounds")}
        r["sampler"] = {**r["sampler"], "num_children": size["num_children"], "workers": 1}
        r["train"] = {**r["train"], "iterations": size["iterations"], "threads": 1}
        return {**r, **common}
    upto = ORDER.index(variant)
    demo = dict(s["demo"]) if upto >= ORDER.index("slowed_demo") else {"seed": 1000, "episodes": 1}
    sampler = {"num_children": size["num_children"], "seed": 0, "workers": 1,
               "expert_step_scale": s["sampler"].get("expert_step_scale", 0.0) if upto >= 1 else 0.0,
               "phases": {**(outward if upto >= ORDER.index("outward") else {}),
                          **(phases if upto >= ORDER.index("phases") else {})}}
    r = {"demo": demo, "sampler": sampler, "train": train, **common}
    if upto >= ORDER.index("rounds"):
        r["rounds"] = dict(THREE_ROUNDS)
    return r


def variants_of(task: str, wanted) -> list:
    """``wanted`` in ``ORDER``, without ``phases`` where the recipe has no phase but the outward one."""
    has_phases = bool(set(shipped(task).get("sampler", {}).get("phases", {})) - {"outward"})
    return [v for v in ORDER if v in wanted and (v != "phases" or has_phases)]


def build(task: str, variant: str, scale: str, out: str) -> dict:
    """Build one variant (resuming) and write its examination summary; returns the summary."""
    work = Path(out) / scale / task / variant
    checkpoint, seconds = timed_build(task, work, variant_recipe(task, variant, scale))
    quality = json.loads((work / "examination" / "quality.json").read_text())
    result = dict(task=task, variant=variant, scale=scale, recipe=variant_recipe(task, variant, scale),
                  build_seconds=round(seconds), checkpoint=str(checkpoint), **examination_measures(quality),
                  policy_final_mean={name: sum(c[-1] for c in curves) / len(curves)
                                     for name, curves in quality.get("curves", {}).items() if curves})
    dest = RESULTS / scale / task / f"{variant}.json"
    dest.parent.mkdir(parents=True, exist_ok=True)
    dest.write_text(json.dumps(result, indent=1) + "\n")
    return result


def sac_configs(jobs, scale: str, out: str, seeds, steps: int) -> list:
    """One state-preset RLConfig per built (task, variant) and seed, paid by that variant's reward."""
    return drem_sac_configs([(task, Path(out) / scale / task / variant / "drem.pt",
                              Path(out) / scale / "sac" / task / variant) for task, variant in jobs], seeds, steps)


def copy_runs(configs) -> None:
    """The small files of every run into ``docs/results/ablation`` (``<scale>/<task>/<variant>/seed<S>``)."""
    for c in configs:
        scale, _, task, variant, seed = Path(c.out).parts[-5:]
        copy_run_files(Path(c.out), RESULTS / scale / task / variant / seed)


def sac_cell(folder: Path, steps: int) -> str:
    """A variant's SAC success at ``steps``, per seed, from its committed ``seed<S>/eval.csv`` files (where a run
    stopped short of ``steps``: its success at its last evaluation and that step)."""
    cells = []
    for run in sorted(folder.glob("seed*/eval.csv")):
        rows = [line.split(",") for line in run.read_text().splitlines()[1:] if line]
        if not rows:
            continue
        step, success = int(rows[-1][0]), float(rows[-1][1])
        best = max(float(r[1]) for r in rows)
        cell = f"{success:.0%}" if step >= steps else f"{success:.0%} at {step:,}"
        cells.append(cell + (f" (best {best:.0%})" if best > success else ""))
    return " / ".join(cells) or "not run"


def table(scales, steps: int) -> str:
    """The ablation's table (markdown) from ``docs/results/ablation``: each variant's examination and its SAC."""
    lines = ["| task | scale | variant | value order | AUROC | expert end, held-out | Direct Success end | "
             f"floor beside / inserted | build | state SAC at {steps:,} steps, per seed |", "| --- " * 10 + "|"]
    for scale in scales:
        for task_dir in sorted((RESULTS / scale).glob("*")):
            done = {p.stem: json.loads(p.read_text()) for p in task_dir.glob("*.json")}
            for variant in (v for v in ORDER if v in done):
                r = done[variant]
                final = r.get("policy_final_mean") or {}
                # A build that ran across interrupted invocations before their time was kept has none.
                build = "not measured" if r["build_seconds"] is None else f"{r['build_seconds'] / 60:.0f} min"
                lines.append(
                    f"| {task_dir.name} | {scale} | `{variant}` | {r['value_order_spearman']:.3f} | "
                    f"{r['final_reward_auroc']:.3f} | {r['expert_end_heldout']:.2f} | "
                    f"{final.get('direct_success', float('nan')):.2f} | "
                    f"{r.get('floor_beside_over_inserted', float('nan')):.2f} | {build} | "
                    f"{sac_cell(task_dir / variant, steps)} |")
    return "\n".join(lines)


def main() -> None:
    """Build every task x variant, two at a time, then train SAC on each through the sweep."""
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--tasks", nargs="+", default=[])
    p.add_argument("--variants", nargs="+", default=list(ORDER), choices=ORDER)
    p.add_argument("--scale", default="pilot", choices=list(SCALES))
    p.add_argument("--seeds", nargs="*", type=int, default=[0])
    p.add_argument("--steps", type=int, default=50_000)
    p.add_argument("--out", default="outputs/ablation")
    p.add_argument("--table", action="store_true", help="print the table of the committed results and stop")
    args = p.parse_args()
    if args.table:
        print(table([s for s in SCALES if (RESULTS / s).is_dir()], args.steps))
        return
    if not args.tasks:
        p.error("--tasks is required to build and train")
    # In the order given: the runs of the first variants named start first.
    jobs = [(t, v) for v in dict.fromkeys(args.variants) for t in args.tasks if v in variants_of(t, [v])]
    # spawn: the parent has SAPIEN and torch loaded, which a forked child must not share.
    with ProcessPoolExecutor(max_workers=2, mp_context=multiprocessing.get_context("spawn")) as pool:
        for result in pool.map(build, *zip(*[(t, v, args.scale, args.out) for t, v in jobs])):
            print(json.dumps({k: result[k] for k in ("task", "variant", "value_order_spearman",
                                                     "final_reward_auroc", "build_seconds")}), flush=True)
    if args.seeds:
        from drem_maniskill.rl.sweep import run_sweep

        configs = sac_configs(jobs, args.scale, args.out, args.seeds, args.steps)
        run_sweep(configs, Path(args.out) / args.scale / "sac")
        copy_runs(configs)


if __name__ == "__main__":
    main()
