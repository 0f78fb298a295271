"""State SAC on a general-recipe build's reward fine-tuned during the run (the ``drem-rounds`` reward).

    python experiments/online_rounds.py --task DPegInHole-v1 \
        --variant even_path_outward_twist_far_fine_slide_wander_long --seeds 0
    python experiments/online_rounds.py --task DPegInHole-v1 \
        --variant even_path_outward_twist_fine_slide_long --seeds 0 --stall-label start

Reads the build ``<out>/<task>/<variant>/`` (its ``drem.pt`` and ``tree.h5``) that ``experiments/general_recipe.py``
made, trains ``<out>/<task>/sac/<variant>_online_rounds/seed<S>`` (``..._online_stalls_<label>`` with stalls looked
for) through the sweep, as the recipe's state runs, and copies each run's small files and every update's record
(traps and stalls found, what they were paid before and after) into the same place under
``docs/results/general_recipe/``.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
import general_recipe as g  # noqa: E402  (experiments/ is the folder)

# Ten updates in a 50,000-step run, each as long a fine-tuning as an offline round's, on at most half its traps.
ONLINE = dict(update_every=5_000, iterations=1_000, trap_share=0.8, max_negatives=500)
# With stalls: a failed episode's last quarter, as the offline stall rounds searched.
STALLS = dict(stall_window=0.25, stall_rise=0.02)


def configs(task: str, variant: str, out: Path, seeds, steps: int, options: dict) -> list:
    """The runs' ``RLConfig``: ``general_recipe.drem_sac_configs``' with the ``drem-rounds`` reward."""
    import dataclasses

    build = out / task / variant
    name = f"{variant}_online_stalls_{options['stall_label']}" if options.get("stall_window") else \
        f"{variant}_online_rounds"
    runs = g.drem_sac_configs([(task, build / "drem.pt", out / task / "sac" / name)], seeds, steps)
    return [dataclasses.replace(c, reward="drem-rounds", reward_kwargs=dict(tree=str(build / "tree.h5"), **options))
            for c in runs]


def update_records(run: Path) -> list:
    """Each update's header record and what its traps were paid, from the run's fine-tuned checkpoints."""
    from drem_maniskill.drem.checkpoint import load_checkpoint
    from drem_maniskill.drem.reward import DREMReward
    from drem_maniskill.pipeline.negatives import paid_on_negatives

    rows = []
    folders = sorted((run / "drem-rounds").glob("update_*"), key=lambda p: int(p.name.split("_")[1]))
    for folder in folders:
        if not (folder / "drem.pt").is_file():
            continue
        header, _ = load_checkpoint(str(folder / "drem.pt"))
        paid = paid_on_negatives(DREMReward.from_checkpoint(str(folder / "drem.pt")), folder / "negatives.h5")
        rows.append(dict(**header["online_rounds"], paid_after=round(float(paid.mean()), 4)))
    return rows


def main() -> None:
    """Train, then copy the runs' files and update records into the docs."""
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--task", required=True)
    p.add_argument("--variant", required=True, help="a general_recipe.py build (its drem.pt and tree.h5)")
    p.add_argument("--seeds", nargs="+", type=int, default=[0])
    p.add_argument("--steps", type=int, default=50_000)
    p.add_argument("--out", default="outputs/general_recipe")
    from drem_maniskill.pipeline.online_rounds import STALL_LABELS

    p.add_argument("--stall-label", choices=STALL_LABELS, default=None,
                   help="look for stalls too (STALLS), labelled so; default: traps only")
    args = p.parse_args()
    from drem_maniskill.rl.sweep import run_sweep

    out = Path(args.out)
    options = ONLINE if args.stall_label is None else dict(ONLINE, **STALLS, stall_label=args.stall_label)
    runs = configs(args.task, args.variant, out, args.seeds, args.steps, options)
    run_sweep(runs, out, cpus_per_trial=2)
    for c in runs:
        dest = g.RESULTS / Path(c.out).relative_to(out)
        g.copy_run_files(Path(c.out), dest)
        (dest / "updates.json").write_text(json.dumps(update_records(Path(c.out)), indent=1) + "\n")


if __name__ == "__main__":
    main()
