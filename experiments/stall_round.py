"""Stall rounds on a finished general-recipe reward, each followed by state SAC on the reward it leaves.

Round 1 of ``build-reward``'s policy rounds with stall states (``stall_window``) on a general-recipe build of
``experiments/general.py`` (``<out>/build/<task>``), its policy being one of that build's 50,000-step state SAC runs
(``<out>/<task>/drem/seed<S>``, ``--policy-seed``): the run a round with ``sac_steps = 50,000`` trains, so it is not
trained again. The round collects the run's failed episodes' traps and stalls, fine-tunes, examines and calibrates in
``<out>/stall/<task>`` (``build_reward`` with the general recipe plus ``stall_rounds(1)``: its demo, tree and first
training are the build's, linked). State SAC on the new reward (``--seeds``) trains through the sweep into
``<out>/stall/<task>/sac/seed<S>``. ``--round K`` goes on from round ``K - 1``'s folder the same way, its policy that
round's SAC run, into ``<out>/stall<K>/<task>``. The round's record and examination measures, and each run's small
files, go to ``docs/results/general/<task>/stall_round[_<K>]/``. Rerunning the command resumes every stage.

    .venv/bin/python experiments/stall_round.py --task SquarePegInHole-v1 --policy-seed 0 --seeds 0 1
    .venv/bin/python experiments/stall_round.py --task SquarePegInHole-v1 --round 2 --policy-seed 0 --seeds 0
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import shutil
from pathlib import Path

from general_recipe import examination_measures, sac_on_reward  # experiments/ is the folder

RESULTS = Path("docs/results/general")
# What the round's SAC config may differ in from the run it takes: where it lives, what pays it (the same file,
# sha256-checked on resume), how it is evaluated, whether its env steps in a child process, its float precision in
# training (the round needs the states a policy reaches, not its training speed), and its seed (a round's is
# seed + k - 1; either is one SAC run on the round's reward).
ROUND_ONLY = {"out", "reward_checkpoint", "eval_every", "eval_episodes", "steps", "overlap_env", "train_bf16", "seed"}


def stall_rounds(rounds: int) -> dict:
    """The recipe's ``[rounds]``: ``rounds`` rounds with stalls, each from a 50,000-step policy."""
    return {"rounds": {"rounds": rounds, "sac_steps": 50_000, "episodes": 20, "iterations": 1_000,
                       "stall_window": 0.25}}


def folders(out: Path, task: str, k: int) -> tuple:
    """Round ``k``'s work folder, the folder it goes on from, and the folder of the SAC runs its policy comes from."""
    work = out / ("stall" if k == 1 else f"stall{k}") / task
    if k == 1:
        return work, out / "build" / task, out / task / "drem"
    previous = folders(out, task, k - 1)[0]
    return work, previous, previous / "sac"


def link_build(build: Path, work: Path, k: int) -> None:
    """The demo, tree, first training and rounds before ``k`` of ``build`` in ``work`` as hard links (their stages are
    then skipped)."""
    for name in ("expert", "tree.h5", "reward", *(f"rounds/round_{j}" for j in range(1, k))):
        src, dest = build / name, work / name
        if dest.exists():
            continue
        if src.is_dir():
            shutil.copytree(src, dest, copy_function=os.link)
        else:
            dest.parent.mkdir(parents=True, exist_ok=True)
            os.link(src, dest)


def place_policy(task: str, work: Path, run: Path, rounds, k: int) -> None:
    """The finished SAC run ``run`` as round ``k``'s policy (``rounds/round_<k>/sac``), its config the round's."""
    from drem_maniskill.pipeline.policy_rounds import round_policy_config
    from drem_maniskill.rl.config import RLConfig

    round_dir = work / "rounds" / f"round_{k}"
    dest = round_dir / "sac"
    if dest.exists():
        return
    paid_by = work / ("reward" if k == 1 else f"rounds/round_{k - 1}/train") / "drem.pt"
    config = round_policy_config(task, paid_by, rounds, k, round_dir)
    saved = RLConfig.load(run / "config.json")
    differ = {f.name for f in dataclasses.fields(config) if getattr(config, f.name) != getattr(saved, f.name)}
    if differ - ROUND_ONLY:
        raise ValueError(f"{run} is not the SAC run round {k} trains: it differs in {sorted(differ - ROUND_ONLY)}")
    shutil.copytree(run, dest, ignore=shutil.ignore_patterns(".lock"))
    config.save(dest / "config.json")


def main() -> None:
    """Run round ``--round`` on the folder before it, then SAC on the reward it leaves, through the sweep."""
    from drem_maniskill.drem.checkpoint import load_checkpoint
    from drem_maniskill.pipeline.build_reward import build_reward
    from drem_maniskill.pipeline.recipe import GENERAL_DEFAULTS, load_recipe, merge

    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--task", required=True)
    p.add_argument("--round", type=int, default=1, help="the round (from the folder of the round before it)")
    p.add_argument("--policy-seed", type=int, default=0, help="the SAC run taken as the round's policy")
    p.add_argument("--seeds", nargs="*", type=int, default=[0, 1], help="state SAC seeds on the new reward")
    p.add_argument("--steps", type=int, default=50_000)
    p.add_argument("--out", default="outputs/general")
    args = p.parse_args()
    out, task = Path(args.out), args.task
    work, previous, runs = folders(out, task, args.round)
    recipe = merge(GENERAL_DEFAULTS, stall_rounds(args.round))
    work.mkdir(parents=True, exist_ok=True)
    link_build(previous, work, args.round)
    place_policy(task, work, runs / f"seed{args.policy_seed}", load_recipe(task, "full", recipe).rounds_config(),
                 args.round)
    checkpoint = build_reward(task, scale="full", out=work, recipe=recipe)
    header, _ = load_checkpoint(str(checkpoint))
    quality = json.loads((work / "quality.json").read_text())
    dest = RESULTS / task / ("stall_round" if args.round == 1 else f"stall_round_{args.round}")
    dest.mkdir(parents=True, exist_ok=True)
    summary = dict(task=task, policy=str(runs.relative_to(out) / f"seed{args.policy_seed}"),
                   recipe_rounds=stall_rounds(args.round)["rounds"],
                   round=header["rounds"][-1], **examination_measures(quality))
    (dest / "examination.json").write_text(json.dumps(summary, indent=1) + "\n")
    print(json.dumps(summary["round"]), flush=True)
    sac_on_reward(task, checkpoint, work / "sac", args.seeds, args.steps, out, dest)


if __name__ == "__main__":
    main()
