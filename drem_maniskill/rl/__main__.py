"""``python -m drem_maniskill.rl train-policy|compare``: the two commands of docs/rl.md over this package."""

from __future__ import annotations

import argparse
import json
import sys

from drem_maniskill.utils.cli import run_command


def _cmd_train_policy(args) -> None:
    from drem_maniskill.envs import check_env_id
    from drem_maniskill.rl.algos import algo_spec
    from drem_maniskill.rl.config import RLConfig
    from drem_maniskill.rl.rewards import reward_spec
    from drem_maniskill.rl.train_policy import train_policy
    from drem_maniskill.utils.config_cli import apply_overrides, overrides_from_args

    config = apply_overrides(RLConfig.preset(args.preset), overrides_from_args(args, RLConfig, skip=RL_SKIP))
    # The clear errors before anything heavy loads.
    check_env_id(config.task)
    reward_spec(config.reward)
    algo_spec(config.algo)
    print(f"policy config: {json.dumps(config.to_dict())}")
    result = train_policy(config)
    print(json.dumps(result, indent=2))


def _cmd_compare(args) -> None:
    from drem_maniskill.rl.compare import compare_runs

    result = compare_runs(args.runs, args.out, band=args.band)
    print(open(result["markdown"]).read())
    print(f"plot: {result['png']}, numbers: {result['json']}")


# RLConfig fields whose flag differs from the field's name, or takes fixed values.
RL_ALIASES = {"train_bf16": ["--bf16"]}
RL_SKIP = ("preset",)  # --preset picks the starting config


def _rl_choices() -> dict:
    """Allowed values of the RLConfig fields that have a fixed set (reward and algo list theirs in their errors)."""
    from drem_maniskill.drem.reward import DREM_FORMS

    return {"drem_form": list(DREM_FORMS), "obs_norm": ["state", "ft"], "sim_backend": ["cpu", "gpu"]}


def add_subcommands(sub) -> None:
    """Add ``train-policy`` and ``compare`` to an argparse subparsers object (here and in ``drem-maniskill``)."""
    from drem_maniskill.rl.config import PRESETS, RLConfig
    from drem_maniskill.utils.config_cli import add_dataclass_args

    p = sub.add_parser("train-policy", help="SAC on a task with a reward chosen by name; rerun to resume",
                       description="SAC on a task with a reward chosen by name; rerun to resume. Every flag but "
                                   "--preset sets the RLConfig field of its name, on top of the preset.")
    p.add_argument("--preset", default="light",
                   help=f"one of {', '.join(PRESETS)}: state: no images, for reward studies; light: images on this "
                        "CPU; paper: the paper's observations, GPU (default: %(default)s)")
    add_dataclass_args(p, RLConfig, skip=RL_SKIP, aliases=RL_ALIASES, choices=_rl_choices(),
                       presets={name: RLConfig.preset(name) for name in PRESETS})
    p.set_defaults(func=_cmd_train_policy)
    p = sub.add_parser("compare", help="success against env steps per task and reward, with a table")
    p.add_argument("runs", nargs="+", help="run dirs of train-policy")
    p.add_argument("--out", default="outputs/rl/comparison", help="output dir (default: %(default)s)")
    p.add_argument("--band", default="minmax", choices=["minmax", "std"], help="spread over seeds")
    p.set_defaults(func=_cmd_compare)


def build_parser() -> argparse.ArgumentParser:
    """Parser of ``python -m drem_maniskill.rl``."""
    parser = argparse.ArgumentParser(prog="python -m drem_maniskill.rl", description=__doc__)
    add_subcommands(parser.add_subparsers(dest="command", required=True))
    return parser


def main(argv=None) -> int:
    """Entry point."""
    return run_command("python -m drem_maniskill.rl", build_parser().parse_args(argv))


if __name__ == "__main__":
    sys.exit(main())
