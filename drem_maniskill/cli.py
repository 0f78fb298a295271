"""``drem-maniskill``: one subcommand per stage, each a thin shell over a library function."""

from __future__ import annotations

import argparse
import json
import sys


def _cmd_demo(args) -> None:
    from drem_maniskill.demo import run_demo

    summary = run_demo(out=args.out, tasks=args.tasks, episodes=args.episodes, seed=args.seed)
    for task, s in summary.items():
        print(f"{task}: expert success {sum(s['success'])}/{len(s['success'])}, lengths {s['lengths']}")
        for p in s["plots"]:
            print(f"  wrote {p}")
    print(f"summary: {args.out}/summary.json")


def _cmd_record_expert(args) -> None:
    from drem_maniskill.recording import record_expert

    seeds = range(args.seed, args.seed + args.episodes)
    result = record_expert(args.task, args.out, seeds=seeds, obs_mode=args.obs_mode, name=args.name, save_video=args.video)
    print(json.dumps({"trajectory": result.h5_path, "metadata": result.json_path, "success_rate": result.success_rate,
                      "lengths": result.lengths}, indent=2))


def _cmd_scripted_success(args) -> None:
    from drem_maniskill.scripted import success_rate

    result = success_rate(args.task, args.policy, seeds=range(args.seed, args.seed + args.episodes))
    print(json.dumps(result, indent=2))


def build_parser() -> argparse.ArgumentParser:
    """The argument parser of the ``drem-maniskill`` command."""
    from drem_maniskill.demo import TASKS

    parser = argparse.ArgumentParser(prog="drem-maniskill", description=__doc__)
    sub = parser.add_subparsers(dest="command", required=True)

    p = sub.add_parser("demo", help="roll out the expert on both tasks; write image strips and F/T plots")
    p.add_argument("--out", default="outputs/demo", help="output folder (default: %(default)s)")
    p.add_argument("--tasks", nargs="+", default=list(TASKS), help="task ids (default: both)")
    p.add_argument("--episodes", type=int, default=2, help="expert episodes per task (default: %(default)s)")
    p.add_argument("--seed", type=int, default=0, help="first episode seed (default: %(default)s)")
    p.set_defaults(func=_cmd_demo)

    p = sub.add_parser("record-expert", help="record scripted-expert episodes in ManiSkill's .h5/.json format")
    p.add_argument("--task", default="PegInHole-v1", help="env id (default: %(default)s)")
    p.add_argument("--out", default="outputs/expert", help="output folder (default: %(default)s)")
    p.add_argument("--episodes", type=int, default=1, help="number of episodes (default: %(default)s)")
    p.add_argument("--seed", type=int, default=0, help="first episode seed (default: %(default)s)")
    p.add_argument("--obs-mode", default="rgb", help="observation mode to record (default: %(default)s)")
    p.add_argument("--name", default="expert", help="file name stem (default: %(default)s)")
    p.add_argument("--video", action="store_true", help="also write an mp4 per episode")
    p.set_defaults(func=_cmd_record_expert)

    p = sub.add_parser("scripted-success", help="success rate of a scripted policy over many seeds")
    p.add_argument("--task", default="PegInHole-v1", help="env id (default: %(default)s)")
    p.add_argument("--policy", default="expert", help="expert, direct_success, align_success, search_fail, random")
    p.add_argument("--episodes", type=int, default=100, help="number of seeds (default: %(default)s)")
    p.add_argument("--seed", type=int, default=0, help="first seed (default: %(default)s)")
    p.set_defaults(func=_cmd_scripted_success)
    return parser


def main(argv=None) -> int:
    """Entry point of the ``drem-maniskill`` console script."""
    args = build_parser().parse_args(argv)
    import drem_maniskill  # noqa: F401  (registers the tasks)

    args.func(args)
    return 0


if __name__ == "__main__":
    sys.exit(main())
