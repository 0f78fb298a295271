"""``drem-maniskill``: one subcommand per stage, each a thin shell over a library function."""

from __future__ import annotations

import argparse
import json
import sys

from drem_maniskill.utils.cli import run_command


def _cmd_demo(args) -> None:
    from drem_maniskill.demo import run_demo

    summary = run_demo(out=args.out, tasks=args.tasks, episodes=args.episodes, seed=args.seed, scale=args.scale,
                       drem=not args.no_drem)
    for task, s in summary.items():
        print(f"{task}: expert success {sum(s['success'])}/{len(s['success'])}, lengths {s['lengths']}")
        if "checkpoint" in s:
            print(f"  reward checkpoint: {s['checkpoint']}")
            print(f"  quality: {json.dumps(s['quality'])}")
        for p in s["plots"]:
            print(f"  plot: {p}")
    print(f"summary: {args.out}/summary.json")


def _cmd_record_expert(args) -> None:
    from drem_maniskill.experts import record_expert

    seeds = range(args.seed, args.seed + args.episodes)
    try:
        env_kwargs = json.loads(args.env_kwargs)
    except json.JSONDecodeError as err:
        raise SystemExit(f"--env-kwargs must be a JSON object, e.g. '{{\"sim_backend\": \"cpu\"}}': {err}")
    result = record_expert(args.task, args.out, seeds=seeds, obs_mode=args.obs_mode, name=args.name, save_video=args.video,
                           env_kwargs=env_kwargs, descent_step=args.descent_step, descend_from=args.descend_from)
    print(json.dumps({"trajectory": result.h5_path, "metadata": result.json_path, "success_rate": result.success_rate,
                      "lengths": result.lengths}, indent=2))


def _cmd_scripted_success(args) -> None:
    from drem_maniskill.experts import success_rate

    result = success_rate(args.task, args.policy, seeds=range(args.seed, args.seed + args.episodes))
    print(json.dumps(result, indent=2))


def _cmd_sample(args) -> None:
    from drem_maniskill.pipeline.sampling import SamplerConfig, backward_sample

    overrides = {k: v for k, v in dict(num_children=args.num_children, num_seeds=args.num_seeds, delta=args.delta,
                                       max_depth=args.max_depth, action_scale=args.action_scale, seed=args.seed,
                                       episode=args.episode, workers=args.workers, expert_step_scale=args.expert_step_scale,
                                       randomize_colors=args.randomize_colors,
                                       randomize_placement=args.randomize_placement, outward_depth=args.outward_depth,
                                       outward_lineages=args.outward_lineages,
                                       outward_children=args.outward_children, face_depth=args.face_depth,
                                       face_lineages=args.face_lineages, face_children=args.face_children,
                                       face_step=args.face_step, side_depth=args.side_depth,
                                       side_step=args.side_step, push_children=args.push_children,
                                       goal_presses=args.goal_presses, turn_depth=args.turn_depth,
                                       turn_children=args.turn_children).items() if v is not None}
    config = SamplerConfig.preset(args.preset, **overrides)
    print(f"sampler config: {config}")
    path = backward_sample(args.expert, args.out, config)
    from drem_maniskill.pipeline.dataset import tree_report

    print(f"progress tree: {path}")
    print(f"regions around the opening: {json.dumps(tree_report(path))}")


def _cmd_train_reward(args) -> None:
    from drem_maniskill.drem.model import ModelConfig
    from drem_maniskill.pipeline.dataset import dataset_modalities
    from drem_maniskill.pipeline.train_reward import TrainConfig, train_reward

    config = TrainConfig.preset(args.preset)
    # Default: every modality the tree holds (a stock ManiSkill task has no F/T sensor).
    modalities = tuple(args.modalities) if args.modalities else dataset_modalities(args.dataset)
    model = ModelConfig(**{**config.model.to_dict(), "modalities": modalities,
                           **({"image_size": args.image_size} if args.image_size else {})})
    overrides = {k: v for k, v in dict(iterations=args.iterations, pairs_per_batch=args.pairs, seed=args.seed,
                                       threads=args.threads).items() if v is not None}
    config = TrainConfig(**{**{f: getattr(config, f) for f in config.__dataclass_fields__}, **overrides, "model": model})
    print(f"training config: {config}")
    path = train_reward(args.dataset, args.out, config)
    print(f"reward checkpoint: {path}")


def _cmd_calibrate_support(args) -> None:
    from drem_maniskill.pipeline.support import calibrate_support

    result = calibrate_support(args.checkpoint, args.dataset, args.out)
    print(json.dumps({k: result[k] for k in ("nodes", "quantile", "tau", "max", "median")}, indent=2))


def _cmd_examine(args) -> None:
    from drem_maniskill.pipeline.examine import examine

    result = examine(args.task, args.checkpoint, seeds=range(args.seed, args.seed + args.episodes), out_dir=args.out)
    keys = ("value_order_spearman", "final_reward_auroc", "random_mean_reward", "search_fail_contact_loss",
            "search_fail_first_contact_loss", "contact_plateau", "colour_spread", "held_positions", "inserted_reward_std",
            "success_rate", "spearman_with_normalized_dense", "spearman_with_insertion_depth",
            "spearman_with_normalized_dense_expert")
    print(json.dumps({k: result.get(k) for k in keys}, indent=2))
    print(f"plot: {args.out}/examination.png, numbers: {args.out}/quality.json")


def _cmd_run_script(args) -> None:
    from drem_maniskill.launcher import run_module, run_script

    extra = args.args[1:] if args.args[:1] == ["--"] else args.args
    (run_module if args.module else run_script)(args.script, extra)


def build_parser() -> argparse.ArgumentParser:
    """The argument parser of the ``drem-maniskill`` command."""
    from drem_maniskill.envs import TASKS

    parser = argparse.ArgumentParser(prog="drem-maniskill", description=__doc__)
    sub = parser.add_subparsers(dest="command", required=True)

    p = sub.add_parser("demo", help="the DREM chain at a small scale on both tasks, with plots")
    p.add_argument("--out", default="outputs/demo", help="output folder (default: %(default)s)")
    p.add_argument("--tasks", nargs="+", default=list(TASKS), help="task ids (default: all of ours, %(default)s)")
    p.add_argument("--episodes", type=int, default=2, help="expert episodes per task (default: %(default)s)")
    p.add_argument("--seed", type=int, default=0, help="first episode seed (default: %(default)s)")
    p.add_argument("--scale", default="demo", choices=["demo", "tiny"], help="demo: minutes here; tiny: for CI")
    p.add_argument("--no-drem", action="store_true", help="only record and draw the expert")
    p.set_defaults(func=_cmd_demo)

    p = sub.add_parser("record-expert", help="record scripted-expert episodes in ManiSkill's .h5/.json format")
    p.add_argument("--task", default="PegInHole-v1",
                   help="env id (default: %(default)s)")
    p.add_argument("--out", default="outputs/expert", help="output folder (default: %(default)s)")
    p.add_argument("--episodes", type=int, default=1, help="number of episodes (default: %(default)s)")
    p.add_argument("--seed", type=int, default=0, help="first episode seed (default: %(default)s)")
    p.add_argument("--obs-mode", default="rgb", help="observation mode to record (default: %(default)s)")
    p.add_argument("--name", default="expert", help="file name stem (default: %(default)s)")
    p.add_argument("--video", action="store_true", help="also write an mp4 per episode")
    p.add_argument("--env-kwargs", default="{}",
                   help="JSON of extra gym.make kwargs; ManiSkill's own tasks default to control_mode pd_ee_delta_pose")
    p.add_argument("--descent-step", type=float,
                   help="our tasks: metres per step the expert descends once 6 mm inside the hole (default 0.005), "
                        "and in its first 6 mm where smaller than the entry's 0.002; "
                        "smaller gives the progress tree more depths inside it (docs/drem.md)")
    p.add_argument("--descend-from", type=float,
                   help="our tasks: metres above the socket's top face the aligned expert starts its slow descent "
                        "(default: wherever it aligned, often 2 cm up); above it, it approaches the pre-insertion point "
                        "6 mm above the opening at its approach speed, so fewer of the demo's steps hover (docs/drem.md)")
    p.set_defaults(func=_cmd_record_expert)

    p = sub.add_parser("scripted-success", help="success rate of a scripted policy over many seeds")
    p.add_argument("--task", default="PegInHole-v1", help="env id (default: %(default)s)")
    p.add_argument("--policy", default="expert", help="expert, direct_success, align_success, search_fail, random")
    p.add_argument("--episodes", type=int, default=100, help="number of seeds (default: %(default)s)")
    p.add_argument("--seed", type=int, default=0, help="first seed (default: %(default)s)")
    p.set_defaults(func=_cmd_scripted_success)

    p = sub.add_parser("examine", help="examine a DREM reward with the four scripted policies; plot and JSON")
    p.add_argument("--task", default="PegInHole-v1", help="env id (default: %(default)s)")
    p.add_argument("--checkpoint", required=True, help="reward checkpoint (.pt)")
    p.add_argument("--out", default="outputs/examination", help="output folder (default: %(default)s)")
    p.add_argument("--episodes", type=int, default=20, help="seeds per policy (default: %(default)s)")
    p.add_argument("--seed", type=int, default=0, help="first seed; keep clear of the expert's (default: %(default)s)")
    p.set_defaults(func=_cmd_examine)

    p = sub.add_parser("sample", help="backward sampling: build the task progress tree from an expert trajectory")
    p.add_argument("--expert", required=True, help="expert trajectory .h5 (RecordEpisode format, .json beside it)")
    p.add_argument("--out", default="outputs/tree.h5", help="dataset to write (default: %(default)s); resumes from <out>.partial")
    p.add_argument("--preset", default="paper", choices=["paper", "quick", "tiny"], help="paper: M=500; quick: M=24")
    p.add_argument("--num-children", type=int, help="M, random actions per seed")
    p.add_argument("--num-seeds", type=int, help="N, seeds kept per depth (paper: 1)")
    p.add_argument("--delta", type=float, help="stop when N*delta seeds are in the start region")
    p.add_argument("--max-depth", type=int, help="give up past this depth")
    p.add_argument("--action-scale", type=float, help="random actions uniform in [-s, s]")
    p.add_argument("--expert-step-scale", type=float,
                   help="actions at each depth span this many times the expert's step there (0: the paper's fixed range)")
    p.add_argument("--randomize-colors", action=argparse.BooleanOptionalAction, default=None,
                   help="fresh part and socket colours per child (default: on)")
    p.add_argument("--randomize-placement", action=argparse.BooleanOptionalAction, default=None,
                   help="each child's scene moved to a fresh socket placement, robot with it (default: on)")
    p.add_argument("--outward-depth", type=int,
                   help="depths sampled past the start region, away from the expert's path (not in the paper; default 0: off)")
    p.add_argument("--outward-lineages", type=int, help="outward directions, one lineage each (default: 12)")
    p.add_argument("--outward-children", type=int, help="random actions per outward seed and depth (default: 100)")
    p.add_argument("--face-depth", type=int,
                   help="depths of lineages sliding the part over the socket's face from the opening (not in the paper; "
                        "default 0: off)")
    p.add_argument("--face-lineages", type=int, help="face directions, one lineage each (default: 8)")
    p.add_argument("--face-children", type=int, help="random actions per face seed and depth (default: 60)")
    p.add_argument("--face-step", type=float, help="metres of travel the face phase's actions span (default: 0.0015)")
    p.add_argument("--side-depth", type=int,
                   help="depths the face lineages go on, over the face's edge and down beside the socket's block (not in "
                        "the paper; needs --face-depth; default 0: off)")
    p.add_argument("--side-step", type=float, help="metres of travel the side phase's actions span (default: 0.004)")
    p.add_argument("--push-children", type=int,
                   help="full-range random actions from every face and side seed, labelled one past it: hard presses "
                        "away from the goal (not in the paper; needs --face-depth; default 0: off)")
    p.add_argument("--goal-presses", type=int,
                   help="random actions from the goal pushing down over the whole range (sideways and twisting within the "
                        "goal's own range), labelled depth 1: the inserted part pressed on the opening's floor (not in "
                        "the paper; default 0: off)")
    p.add_argument("--turn-depth", type=int,
                   help="depths of lineages turning the part about its axis and tilting it near the opening, above it "
                        "and on the face (not in the paper; needs --face-depth; default 0: off)")
    p.add_argument("--turn-children", type=int, help="random actions per turn seed and depth (default: 24)")
    p.add_argument("--seed", type=int, help="random seed")
    p.add_argument("--episode", type=int, help="episode of the expert file")
    p.add_argument("--workers", type=int, help="worker processes")
    p.set_defaults(func=_cmd_sample)

    p = sub.add_parser("train-reward", help="train the DREM progress model on a progress tree")
    p.add_argument("--dataset", required=True, help="progress tree .h5 from `sample`")
    p.add_argument("--out", default="outputs/reward", help="output folder: drem.pt, tb/, train_state.pt (resume)")
    p.add_argument("--preset", default="paper", choices=["paper", "quick", "tiny"],
                   help="paper: 20k iterations at 128 px; quick/tiny: CPU-sized")
    p.add_argument("--modalities", nargs="+", choices=["fixed", "wrist", "ft"], help="inputs (default: all the dataset holds)")
    p.add_argument("--image-size", type=int, help="model input size (multiple of 64)")
    p.add_argument("--iterations", type=int)
    p.add_argument("--pairs", type=int, help="pairs per batch (half neighbours)")
    p.add_argument("--seed", type=int)
    p.add_argument("--threads", type=int, help="torch CPU threads")
    p.set_defaults(func=_cmd_train_reward)

    p = sub.add_parser("calibrate-support", help="tree nodes' reconstruction errors for the drem-guarded reward")
    p.add_argument("--checkpoint", required=True, help="a DREM checkpoint (drem.pt)")
    p.add_argument("--dataset", required=True, help="the progress tree it was trained on")
    p.add_argument("--out", required=True, help="support.json to write (rewards/<task>/support.json for drem-guarded)")
    p.set_defaults(func=_cmd_calibrate_support)

    from drem_maniskill.rl.__main__ import add_subcommands

    add_subcommands(sub)  # train-policy, compare (drem_maniskill/rl, docs/rl.md)

    p = sub.add_parser("run-script", help="run a ManiSkill script (e.g. ppo_cpu.py) with our env ids registered")
    p.add_argument("script", help="the script, e.g. ManiSkill's examples/baselines/ppo/ppo_cpu.py (with -m: a module)")
    p.add_argument("-m", "--module", action="store_true",
                   help="SCRIPT is a module, run as `python -m`, e.g. mani_skill.examples.benchmarking.gpu_sim")
    p.add_argument("args", nargs=argparse.REMAINDER, help="-- then the script's own arguments")
    p.set_defaults(func=_cmd_run_script)
    return parser


def main(argv=None) -> int:
    """Entry point of the ``drem-maniskill`` console script."""
    args = build_parser().parse_args(argv)
    from drem_maniskill.envs import check_env_id  # registers the tasks

    def check_tasks(args) -> None:
        # An unknown task id fails here, with the ids we know, rather than deep inside gymnasium.
        for task in [getattr(args, "task", None), *(getattr(args, "tasks", None) or [])]:
            if task is not None:
                check_env_id(task)

    return run_command("drem-maniskill", args, check_tasks)


if __name__ == "__main__":
    sys.exit(main())
