"""What a task-agnostic DREM recipe needs: build rewards for stock ManiSkill tasks under recipe variants.

Each variant is a recipe (a dict, the sections of ``tasks/<id>/recipe.toml``) that names nothing about the task:
no phases, no geometry, only the demo of its scripted expert, its success signal and its own cameras. The script
runs ``build_reward`` for every task x variant into ``<out>/<task>/<variant>`` (resumable: rerun the same command)
and writes the examination's measures beside the recipe to ``docs/results/general_recipe/<task>/<variant>.json``.
A finished build's checkpoint, examination and recipe are kept in
``docs/results/general_recipe/<task>/build/<variant>/``; where ``<out>`` lacks them (another machine), a rerun takes
them from there instead of building again.

    .venv/bin/python experiments/general_recipe.py --tasks PushCube-v1 StackCube-v1 --variants base
    .venv/bin/python experiments/general_recipe.py --tasks PlugCharger-v1 --variants base three_rounds
    .venv/bin/python experiments/general_recipe.py --tasks PegInHole-v1 --variants even_path --seeds 0 1 2

With ``--seeds``, state-preset SAC (50,000 steps) trains on each variant's reward through the sweep, two at a time,
into ``<out>/<task>/sac/<variant>/seed<S>``, its small files copied beside the summary.
"""

from __future__ import annotations

import argparse
import json
import signal
import time
from pathlib import Path

import numpy as np

BASE = {
    "demo": {"seed": 1000, "episodes": 1},
    "sampler": {"num_children": 100, "expert_step_scale": 0.0, "seed": 0, "workers": 1},
    "train": {"iterations": 2000, "pairs_per_batch": 16, "threads": 1, "model": {"image_size": 64}},
    "examine": {"first_seed": 0, "episodes": 20},
    "calibrate": {"enabled": False},
}
FIVE_TREES = {"demo": {"episodes": 5, "trees": 5}}
# Each depth's children from the demo's own state: the objects where the demo had them (a pushed cube included).
DEMO_SEEDS = {"sampler": {"seeds_from_demo": True}}
THREE_ROUNDS = {"rounds": {"rounds": 3, "sac_steps": 10000, "episodes": 20, "iterations": 1000}}
# The trees' own resolution (the stock cameras render 128 px): a 4 cm cube is about 4 px wide at 64 px.
FULL_RESOLUTION = {"train": {"model": {"image_size": 128}}}
# The scene's poses from the sim state (beside or instead of the camera): the objects' place, not only the arm's.
POSES = {"train": {"model": {"modalities": ["poses"]}}}
CAMERA_POSES = {"train": {"model": {"modalities": ["fixed", "poses"]}}}
# Scenes with the robot from one depth of the demo and the objects from a deeper one, labelled by the objects' depth.
SWAP = {"scene_swap": {"negatives": True}}
# Trees for a model that reads no camera, sampled without rendering.
NO_IMAGES = {"sampler": {"images": False}}
# Twenty demo episodes of M = 25 each: the node count and scene-swap count of five trees of M = 100, over four times
# the placements (a reward read from poses pays held-out placements less than the demo's own).
TWENTY_SMALL_TREES = {"demo": {"episodes": 20, "trees": 20}, "sampler": {"num_children": 25},
                      "scene_swap": {"max_pairs": 125}}
# The actors' pairwise position differences beside their poses: what is placed where relative to what.
RELATIVE = {"train": {"model": {"poses_relative": True}}}
# The expert-step action range on the demo's path walked in even steps of its median step (no slowed demo).
EVEN_PATH = {"sampler": {"expert_step_scale": 4.0, "even_path": True}}
# The even path graded toward the goal: each step a tenth of the way left, from a quarter of the median step up to it.
GRADED = {"sampler": {"graded_path": 0.1, "graded_finest": 0.25}}
# Lineages leaving the start region in twelve directions (the outward phase reads no geometry).
OUTWARD = {"sampler": {"phases": {"outward": {"depth": 10, "lineages": 12, "children": 100}}}}
# Lineages turning the part about the end effector's axes from the backward seeds nearest the goal (no geometry).
TWIST = {"sampler": {"phases": {"twist": {"depth": 10}}}}
# Lineages moving the part across its approach from the same seeds (no geometry).
SLIDE = {"sampler": {"phases": {"slide": {"depth": 10}}}}
# The same lineages in steps of a tenth of the loop's range there: a part a few millimetres beside the path is labelled
# as many steps farther as the fine steps that took it there, more than the loss's eps of 4 past about 2 mm.
FINE_SLIDE = {"sampler": {"phases": {"slide": {"depth": 12, "step": 0.1}}}}
# Fine slide lineages from every second depth of the whole path (not only the half nearest the goal), across the final
# approach, for twice the steps: a part a centimetre or more beside an opening deeper than half the path, where policies
# on the fine-slide reward stop, is a state the tree labels rather than one the reward guesses at.
FAR_FINE_SLIDE = {"sampler": {"phases": {"slide": {"depth": 24, "step": 0.1, "reach": 1.0, "approach_reach": 0.5}}}}
# Lineages that slide and turn the part at once, each along its own random direction of the five, in fine steps from
# every fourth depth of the whole path: a part beside the opening that is also tilted and turned, a state that lineages
# of one move never reach.
WANDER = {"sampler": {"phases": {"wander": {"depth": 24}}}}
# Two policy rounds whose SAC runs half the 50,000 steps the reward is judged at, so its policy reaches the states
# a trained policy stops in (on USB no policy inserted the plug before 17,500 steps).
TWO_LONG_ROUNDS = {"rounds": {"rounds": 2, "sac_steps": 25000, "episodes": 20, "iterations": 1000}}
# One policy round from a 50,000-step policy, its traps (failed states paid at least depth 9's pay) labelled as far from
# the goal as the start region: the tree's own labels put a part a centimetre beside the path past the start, so a
# trap found there is labelled no nearer than its neighbours.
START_ROUND = {"rounds": {"rounds": 1, "sac_steps": 50_000, "episodes": 20, "iterations": 1000, "trap_label": "start"}}
# A second such round, its policy 50,000 steps of SAC on the first round's reward, its traps the failed states paid at
# least 0.8 of the goal's pay (check-reward's rule): that policy's stops are paid 0.76-0.84, under depth 9's 0.96, so
# the depth rule finds none. Built on the start-round variant, whose round 1 found its traps by depth 9's pay.
TWO_START_ROUNDS = {"rounds": {**START_ROUND["rounds"], "rounds": 2, "trap_share": 0.8}}
# A third such round, its policy 50,000 steps of SAC on the second round's reward.
THREE_START_ROUNDS = {"rounds": {**TWO_START_ROUNDS["rounds"], "rounds": 3}}
# Start rounds whose traps are found by check-reward's rule from the first round on: the wander lineages' policies stop
# where the reward pays 0.8-0.9 of the goal, under the pay of depth 9.
SHARE_START_ROUND = {"rounds": {**TWO_START_ROUNDS["rounds"], "rounds": 1}}
# The paper's 20,000 iterations.
LONG_TRAINING = {"train": {"iterations": 20000}}
# Variant -> the recipe parts merged over BASE, in order.
VARIANTS = {
    "base": (),
    "expert_step_range": ({"sampler": {"expert_step_scale": 4.0}},),
    "even_path": (EVEN_PATH,),
    "even_path_outward": (EVEN_PATH, OUTWARD),
    "even_path_long": (EVEN_PATH, LONG_TRAINING),
    "even_path_outward_long": (EVEN_PATH, OUTWARD, LONG_TRAINING),
    "even_path_outward_twist_long": (EVEN_PATH, OUTWARD, TWIST, LONG_TRAINING),
    "even_path_outward_twist_slide_long": (EVEN_PATH, OUTWARD, TWIST, SLIDE, LONG_TRAINING),
    "graded_path_outward_twist_long": (EVEN_PATH, GRADED, OUTWARD, TWIST, LONG_TRAINING),
    "even_path_outward_twist_fine_slide_long": (EVEN_PATH, OUTWARD, TWIST, FINE_SLIDE, LONG_TRAINING),
    "even_path_outward_twist_far_fine_slide_long": (EVEN_PATH, OUTWARD, TWIST, FAR_FINE_SLIDE, LONG_TRAINING),
    "even_path_outward_twist_far_fine_slide_long_start_round": (EVEN_PATH, OUTWARD, TWIST, FAR_FINE_SLIDE,
                                                                LONG_TRAINING, START_ROUND),
    "even_path_outward_twist_far_fine_slide_long_two_start_rounds": (EVEN_PATH, OUTWARD, TWIST, FAR_FINE_SLIDE,
                                                                     LONG_TRAINING, TWO_START_ROUNDS),
    "even_path_outward_twist_far_fine_slide_long_three_start_rounds": (EVEN_PATH, OUTWARD, TWIST, FAR_FINE_SLIDE,
                                                                       LONG_TRAINING, THREE_START_ROUNDS),
    "even_path_outward_twist_far_fine_slide_wander_long": (EVEN_PATH, OUTWARD, TWIST, FAR_FINE_SLIDE, WANDER,
                                                           LONG_TRAINING),
    "even_path_outward_twist_far_fine_slide_wander_long_start_round": (EVEN_PATH, OUTWARD, TWIST, FAR_FINE_SLIDE,
                                                                       WANDER, LONG_TRAINING, SHARE_START_ROUND),
    "even_path_outward_twist_long_two_rounds": (EVEN_PATH, OUTWARD, TWIST, LONG_TRAINING, TWO_LONG_ROUNDS),
    "longer_training": ({"train": {"iterations": 5000}},),
    "fewer_children": ({"sampler": {"num_children": 50}},),
    "three_rounds": (THREE_ROUNDS,),
    "five_trees": (FIVE_TREES,),
    "more_children": ({"sampler": {"num_children": 500}},),  # five trees' node count in one tree, one placement
    "five_trees_three_rounds": (FIVE_TREES, THREE_ROUNDS),
    "five_trees_demo_seeds": (FIVE_TREES, DEMO_SEEDS),
    "five_trees_demo_seeds_three_rounds": (FIVE_TREES, DEMO_SEEDS, THREE_ROUNDS),
    "five_trees_128px": (FIVE_TREES, FULL_RESOLUTION),
    "five_trees_poses": (FIVE_TREES, POSES),
    "five_trees_camera_poses": (FIVE_TREES, CAMERA_POSES),
    "five_trees_poses_three_rounds": (FIVE_TREES, POSES, THREE_ROUNDS),
    "five_trees_poses_swap": (FIVE_TREES, POSES, SWAP),
    "five_trees_poses_swap_three_rounds": (FIVE_TREES, POSES, SWAP, THREE_ROUNDS),
    "unrendered_five_trees_poses_swap_three_rounds": (FIVE_TREES, POSES, NO_IMAGES, SWAP, THREE_ROUNDS),
    "unrendered_twenty_small_trees_poses_swap_three_rounds": (TWENTY_SMALL_TREES, POSES, NO_IMAGES, SWAP,
                                                              THREE_ROUNDS),
    "unrendered_twenty_small_trees_relative_poses_swap_three_rounds": (TWENTY_SMALL_TREES, POSES, RELATIVE,
                                                                       NO_IMAGES, SWAP, THREE_ROUNDS),
}
# A variant that changes what follows sampling starts from the demo and trees of the one it builds on (so both
# measure the same trees) and, where it only adds rounds, from that one's reward too. One that adds a growable phase
# (``GROWS``) starts from those trees as partial ones: its sampling adds the phase to them.
BUILDS_ON = {"three_rounds": ("base", True),
             "five_trees_three_rounds": ("five_trees", True),
             "five_trees_demo_seeds_three_rounds": ("five_trees_demo_seeds", True),
             "five_trees_128px": ("five_trees", False),
             "even_path_long": ("even_path", False),
             "even_path_outward_long": ("even_path_outward", False),
             "even_path_outward_twist_long": ("even_path_outward_long", False),
             "even_path_outward_twist_slide_long": ("even_path_outward_twist_long", False),
             "even_path_outward_twist_fine_slide_long": ("even_path_outward_long", False),
             "even_path_outward_twist_far_fine_slide_long": ("even_path_outward_twist_long", False),
             "even_path_outward_twist_far_fine_slide_long_start_round": (
                 "even_path_outward_twist_far_fine_slide_long", True),
             "even_path_outward_twist_far_fine_slide_long_two_start_rounds": (
                 "even_path_outward_twist_far_fine_slide_long_start_round", True),
             "even_path_outward_twist_far_fine_slide_long_three_start_rounds": (
                 "even_path_outward_twist_far_fine_slide_long_two_start_rounds", True),
             "even_path_outward_twist_far_fine_slide_wander_long": ("even_path_outward_twist_far_fine_slide_long",
                                                                    False),
             "even_path_outward_twist_far_fine_slide_wander_long_start_round": (
                 "even_path_outward_twist_far_fine_slide_wander_long", True),
             "even_path_outward_twist_long_two_rounds": ("even_path_outward_twist_long", True),
             "five_trees_camera_poses": ("five_trees_poses", False),
             "five_trees_poses_three_rounds": ("five_trees_poses", True),
             "five_trees_poses_swap": ("five_trees_poses", False),
             "five_trees_poses_swap_three_rounds": ("five_trees_poses_swap", True),
             "unrendered_twenty_small_trees_relative_poses_swap_three_rounds": (
                 "unrendered_twenty_small_trees_poses_swap_three_rounds", False)}
GROWS = {"even_path_outward_twist_long", "even_path_outward_twist_slide_long",
         "even_path_outward_twist_fine_slide_long", "even_path_outward_twist_far_fine_slide_long",
         "even_path_outward_twist_far_fine_slide_wander_long"}
RESULTS = Path("docs/results/general_recipe")
RUN_FILES = ("config.json", "eval.csv", "reward_checkpoint.json")
# float32, the env in the trainer's process: as the shipped comparison's runs.
STATE_RUN = dict(train_bf16=False, overlap_env=False)


def recipe(variant: str) -> dict:
    """The recipe dict of a variant: ``BASE`` with the variant's parts merged in."""
    from drem_maniskill.pipeline.recipe import merge

    out = BASE
    for part in VARIANTS[variant]:
        out = merge(out, part)
    return out


def summary(task: str, variant: str, work: Path, seconds: float) -> dict:
    """The measures a general recipe is judged by, from the build's examination and checkpoint header."""
    from drem_maniskill.drem.checkpoint import load_checkpoint

    quality = json.loads((work / "quality.json").read_text())
    header, _ = load_checkpoint(str(work / "drem.pt"))
    return dict(task=task, variant=variant, recipe=recipe(variant), build_seconds=round(seconds),
                value_order_spearman=quality["value_order_spearman"],
                final_reward_auroc=quality["final_reward_auroc"],
                final_reward_auroc_expert_noisy=quality.get("final_reward_auroc_expert_noisy"),
                random_mean_reward=quality["random_mean_reward"],
                robot_only_over_expert=quality.get("robot_only_over_expert"),
                objects_only_over_expert=quality.get("objects_only_over_expert"),
                success_rate=quality["success_rate"], fit=header.get("fit"), rounds=header.get("rounds", []),
                trees=header.get("trees", []),
                # What the expert's end is paid on held-out seeds against the demo's own: the placements the
                # trees saw and those they did not (a gap here is a reward that does not carry to new scenes).
                expert_end_heldout=float(np.mean([c[-1] for c in quality["expert_curves"]])),
                expert_end_demo=expert_end_on_demo_seeds(task, work))


def expert_end_on_demo_seeds(task: str, work: Path) -> float:
    """Mean reward at the end of the scripted expert's episodes on the demo's own seeds (``recipe.json``)."""
    from drem_maniskill.experts.control import ee_control_kwargs
    from drem_maniskill.experts.policies import get_policy
    from drem_maniskill.experts.rollout import rollout
    from drem_maniskill.rl.rewards import REWARDS

    demo = json.loads((work / "recipe.json").read_text())["demo"]
    env = REWARDS["drem"].make(task, dict(obs_mode="state_dict", drem_checkpoint=str(work / "drem.pt"),
                                          drem_form="paper", **ee_control_kwargs(task, {})))
    try:
        seeds = range(demo["seed"], demo["seed"] + demo["episodes"])
        return float(np.mean([rollout(env, get_policy("expert", env, seed=s), s).rewards[-1] for s in seeds]))
    finally:
        env.close()


def reuse_trees(work: Path, source, with_reward: bool, grow: bool = False) -> None:
    """Start a variant (``BUILDS_ON``) from the demo and trees, and with ``with_reward`` the reward and finished policy
    rounds, of the variant built in ``source``; with ``grow``, the trees as partial ones, which its sampling goes on
    from."""
    import shutil

    if source is None or work.exists():
        return
    if not (source / "reward" / "drem.pt" if with_reward else source / "tree.h5").is_file():
        return
    work.mkdir(parents=True)
    names = ["expert"]
    if with_reward:  # finished rounds, not rounds/drem.pt: that file marks the rounds stage done, and a round is added
        names += ["reward", *sorted(p.relative_to(source) for p in source.glob("rounds/round_*"))]
    for name in names:
        shutil.copytree(source / name, work / name)
    for tree in source.glob("tree*.h5"):
        shutil.copyfile(tree, work / (f"{tree.name}.partial" if grow else tree.name))


def place_round_policy(task: str, work: Path, run: Path, variant: str) -> None:
    """The finished SAC run ``run`` as the last round's policy of ``variant`` in ``work``, the rounds before it those
    of the variant built on (``stall_round.place_policy``)."""
    from stall_round import place_policy  # experiments/ is the folder

    from drem_maniskill.pipeline.recipe import load_recipe

    if not (run / "config.json").is_file():
        raise FileNotFoundError(f"{run} holds no SAC run: train it first (--seeds on the variant built on)")
    rounds = load_recipe(task, "full", recipe(variant)).rounds_config()
    place_policy(task, work, run, rounds, rounds.rounds)


def link_demo_and_tree(build: Path, work: Path) -> None:
    """``build``'s demo and tree in ``work`` as symlinks, where ``work`` has none and ``build`` has them: a variant that
    differs only in its training (its demo and sampling stages are then skipped)."""
    import os

    for entry in ("expert", "tree.h5"):
        src, dest = build / entry, work / entry
        if not dest.exists() and src.exists():
            os.symlink(src.resolve(), dest, target_is_directory=src.is_dir())


def add_build_time(work: Path, seconds: float) -> float:
    """Seconds spent building ``work`` over every invocation, so a resumed build reports what it did before too."""
    path = work / "build_seconds.json"
    total = seconds + (json.loads(path.read_text())["seconds"] if path.is_file() else 0.0)
    path.write_text(json.dumps({"seconds": total}) + "\n")
    return total


# What a finished build leaves at its work folder's top that SAC and the summaries read: kept beside the results, a
# later machine (whose outputs/ are gone) restores them instead of building again.
KEPT = ("drem.pt", "quality.json", "examination.png", "recipe.json", "build_seconds.json")


def copy_kept(source: Path, dest: Path) -> None:
    """Copy a build's products (``KEPT``) that ``source`` holds into ``dest``: to keep a build, or to restore it."""
    from drem_maniskill.utils.atomic import copy_file

    dest.mkdir(parents=True, exist_ok=True)
    for name in KEPT:
        if (source / name).is_file():
            copy_file(source / name, dest / name)


def restore_build(work: Path, keep: Path, r) -> bool:
    """Copy a build kept in ``keep`` into ``work`` where ``work`` holds no finished build; a kept build of another
    recipe than ``r`` is refused (``RecipeError``). Returns whether it restored one."""
    from drem_maniskill.pipeline.build_reward import check_same_recipe
    from drem_maniskill.pipeline.recipe import RecipeError

    if (work / "drem.pt").is_file() or not (keep / "drem.pt").is_file():
        return False
    if not (keep / "recipe.json").is_file():
        raise RecipeError(f"{keep} holds a checkpoint without its recipe.json: delete {keep} to build again")
    check_same_recipe(keep / "recipe.json", r)
    copy_kept(keep, work)
    return True


def timed_build(task: str, work: Path, recipe, keep: Path = None) -> tuple:
    """``build_reward`` at full scale into ``work`` (resuming); returns the checkpoint and the seconds spent building
    ``work`` over every invocation, an interrupted one's included (its rerun resumes it). With ``keep``, a finished
    build is copied there, and one found there (and not in ``work``) is restored instead of built."""
    from drem_maniskill.pipeline.build_reward import build_reward, check_same_recipe
    from drem_maniskill.pipeline.recipe import load_recipe

    r = load_recipe(task, "full", recipe)
    if keep is not None:
        restore_build(work, keep, r)
    if all((work / name).is_file() for name in ("drem.pt", "quality.json", "build_seconds.json")):
        # A finished build (its products are copied to the top last); restored, it has no trees to skip stages by.
        check_same_recipe(work / "recipe.json", r)
        return work / "drem.pt", json.loads((work / "build_seconds.json").read_text())["seconds"]

    def stopped(signum, frame):
        raise SystemExit(128 + signum)

    start = time.time()
    # A build stopped with SIGTERM (kill, a session's end) unwinds, so the time it spent is added below.
    previous = signal.signal(signal.SIGTERM, stopped)
    try:
        checkpoint = build_reward(task, scale="full", out=work, recipe=recipe)
    finally:
        signal.signal(signal.SIGTERM, previous)
        seconds = add_build_time(work, time.time() - start)
    if keep is not None:
        copy_kept(work, keep)
    return checkpoint, seconds


EXAM_MEASURES = ("value_order_spearman", "final_reward_auroc", "random_mean_reward", "success_rate",
                 "floor_beside_over_inserted", "mouth_off_axis_over_on_axis")


def examination_measures(quality: dict) -> dict:
    """The examination's measures a recipe is compared by (``EXAM_MEASURES``) and the expert's mean held-out end."""
    return dict({k: quality.get(k) for k in EXAM_MEASURES},
                expert_end_heldout=float(np.mean([c[-1] for c in quality["expert_curves"]])))


def drem_sac_configs(runs, seeds, steps: int) -> list:
    """State-preset SAC configs, one per ``(task, reward checkpoint, folder)`` of ``runs`` and seed, into
    ``<folder>/seed<S>`` (float32, the env in the trainer's process: as the shipped comparison's runs)."""
    from drem_maniskill.rl.config import RLConfig

    return [RLConfig.from_preset("state", task=task, reward="drem", seed=int(seed), steps=int(steps),
                                 out=str(Path(folder) / f"seed{seed}"), reward_checkpoint=str(checkpoint),
                                 **STATE_RUN)
            for task, checkpoint, folder in runs for seed in seeds]


def sac_on_reward(task: str, checkpoint, folder: Path, seeds, steps: int, out: Path, dest: Path) -> None:
    """State SAC on the reward ``checkpoint`` through the sweep (``drem_sac_configs``, runs in ``folder``, the sweep's
    logs in ``out``), each run's small files then into ``dest/drem/seed<S>``."""
    configs = drem_sac_configs([(task, checkpoint, folder)], seeds, steps)
    if configs:
        from drem_maniskill.rl.sweep import run_sweep

        run_sweep(configs, out)
        for c in configs:
            copy_run_files(Path(c.out), dest / "drem" / Path(c.out).name)


def copy_run_files(run: Path, dest: Path) -> None:
    """A run's small files (``RUN_FILES``) into ``dest``, for the docs."""
    import shutil

    dest.mkdir(parents=True, exist_ok=True)
    for name in RUN_FILES:
        if (run / name).is_file():
            shutil.copyfile(run / name, dest / name)


def main() -> None:
    """Build every task x variant and write its summary; with ``--seeds``, train SAC on each through the sweep."""
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--tasks", nargs="+", required=True)
    p.add_argument("--variants", nargs="+", default=["base"], choices=list(VARIANTS))
    p.add_argument("--out", default="outputs/general_recipe")
    p.add_argument("--seeds", nargs="*", type=int, default=[], help="state SAC seeds on each built reward")
    p.add_argument("--steps", type=int, default=50_000)
    p.add_argument("--round-policy", type=int, default=None, metavar="SEED",
                   help="the last round's policy: the finished state SAC run of this seed on the variant built on "
                        "(<out>/<task>/sac/<that variant>/seed<SEED>), which the round would otherwise train again")
    args = p.parse_args()
    for task in args.tasks:
        for variant in args.variants:
            work = Path(args.out) / task / variant
            source, with_reward = BUILDS_ON.get(variant, (None, False))
            reuse_trees(work, Path(args.out) / task / source if source else None, with_reward, variant in GROWS)
            if args.round_policy is not None and source and with_reward:
                place_round_policy(task, work, Path(args.out) / task / "sac" / source / f"seed{args.round_policy}",
                                   variant)
            _, seconds = timed_build(task, work, recipe(variant), keep=RESULTS / task / "build" / variant)
            result = summary(task, variant, work, seconds)
            dest = RESULTS / task / f"{variant}.json"
            dest.parent.mkdir(parents=True, exist_ok=True)
            dest.write_text(json.dumps(result, indent=1) + "\n")
            print(json.dumps({k: result[k] for k in ("task", "variant", "value_order_spearman",
                                                     "final_reward_auroc", "build_seconds")}), flush=True)
    if args.seeds:
        from drem_maniskill.rl.sweep import run_sweep

        out = Path(args.out)
        configs = drem_sac_configs([(t, out / t / v / "drem.pt", out / t / "sac" / v) for t in args.tasks
                                    for v in args.variants], args.seeds, args.steps)
        run_sweep(configs, out)  # the runs lie under out: each logs to out/logs/ by its own folder
        for c in configs:  # <out>/<task>/sac/<variant>/seed<S> -> RESULTS/<task>/sac/<variant>/seed<S>
            copy_run_files(Path(c.out), RESULTS / Path(c.out).relative_to(out))


if __name__ == "__main__":
    main()
