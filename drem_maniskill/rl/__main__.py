"""The reinforcement-learning subcommands of ``drem-maniskill``: ``train-policy``, ``sweep``, ``compare`` (docs/rl.md).

``drem_maniskill.cli.build_parser`` adds them to the one command line with ``add_subcommands``.
"""

from __future__ import annotations

import json
import sys


def _cmd_train_policy(args) -> None:
    from drem_maniskill.envs import check_env_id
    from drem_maniskill.rl.algos import algo_spec
    from drem_maniskill.rl.config import RLConfig
    from drem_maniskill.rl.rewards import reward_spec
    from drem_maniskill.rl.train_policy import train_policy
    from drem_maniskill.utils.config_cli import apply_overrides, overrides_from_args

    config = apply_overrides(RLConfig.from_preset(args.preset), overrides_from_args(args, RLConfig, skip=RL_SKIP))
    # The clear errors before anything heavy loads.
    check_env_id(config.task)
    reward_spec(config.reward)
    algo_spec(config.algo)
    print(f"policy config: {json.dumps(config.to_dict())}")
    result = train_policy(config)
    print(json.dumps(result, indent=2))


def _cmd_sweep(args) -> None:
    from drem_maniskill.rl.sweep import configs_from_args, run_sweep

    configs = configs_from_args(args)  # every unknown name fails here, before Ray starts
    try:
        result = run_sweep(configs, args.out, address=args.address, cpus_per_trial=args.cpus_per_trial,
                           gpus_per_trial=args.gpus_per_trial, max_retries=args.max_retries)
    except ImportError as err:
        raise SystemExit(f"drem-maniskill sweep: error: {err}")
    if result["failed"]:
        raise SystemExit(f"drem-maniskill sweep: {result['failed']} trials failed; rerun the command to resume them")


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
    """Add ``train-policy``, ``sweep`` and ``compare`` to an argparse subparsers object (here, ``drem-maniskill``)."""
    from drem_maniskill.rl.config import PRESETS, RLConfig
    from drem_maniskill.utils.config_cli import add_dataclass_args

    p = sub.add_parser("train-policy", help="SAC on a task with a reward chosen by name; rerun to resume",
                       description="SAC on a task with a reward chosen by name; rerun to resume. Every flag but "
                                   "--preset sets the RLConfig field of its name, on top of the preset.")
    p.add_argument("--preset", default="light",
                   help=f"one of {', '.join(PRESETS)}: state: no images, for reward studies; light: images and F/T on "
                        "this CPU; image: the paper's inputs on this CPU (32 px, F/T for drem only); paper: the "
                        "paper's inputs at 128 px, GPU (default: %(default)s)")
    add_dataclass_args(p, RLConfig, skip=RL_SKIP, aliases=RL_ALIASES, choices=_rl_choices(),
                       presets={name: RLConfig.from_preset(name) for name in PRESETS})
    p.set_defaults(func=_cmd_train_policy)
    _add_sweep(sub)
    p = sub.add_parser("compare", help="success against env steps per task and reward, with a table")
    p.add_argument("runs", nargs="+", help="run dirs of train-policy")
    p.add_argument("--out", default="outputs/rl/comparison", help="output dir (default: %(default)s)")
    p.add_argument("--band", default="minmax", choices=["minmax", "std"], help="spread over seeds")
    p.set_defaults(func=_cmd_compare)


def _add_sweep(sub) -> None:
    """The ``sweep`` subcommand: its grid flags, and every train-policy flag but the ones a trial sets."""
    from drem_maniskill.rl.config import PRESETS, RLConfig
    from drem_maniskill.rl.sweep import SWEEP_FIELDS
    from drem_maniskill.utils.config_cli import add_dataclass_args

    p = sub.add_parser("sweep", help="train-policy over tasks x rewards x seeds (x presets) on Ray; rerun to resume",
                       description="One train-policy run per task x reward x seed (x preset) into "
                                   "OUT/TASK/REWARD/seedS (OUT/PRESET/TASK/... with more than one preset), run "
                                   "on Ray: this machine's cores, or a running cluster with --address. Finished "
                                   "runs are skipped, interrupted ones resume from their checkpoints. Every other "
                                   "flag sets the RLConfig field of its name in every trial, as in train-policy.")
    p.add_argument("--tasks", nargs="+", required=True, help="env ids")
    p.add_argument("--rewards", nargs="+", required=True, help="reward names (rl.rewards.REWARDS)")
    p.add_argument("--seeds", nargs="+", type=int, required=True, help="training seeds")
    p.add_argument("--presets", "--preset", nargs="+", default=["light"], choices=list(PRESETS), metavar="PRESET",
                   help=f"presets among {', '.join(PRESETS)} (default: light)")
    p.add_argument("--steps", type=int, required=True, help="env steps of every run")
    p.add_argument("--out", default="outputs/rl", help="root of the run folders and logs/ (default: %(default)s)")
    p.add_argument("--address", default=None,
                   help="a running Ray cluster (e.g. auto, or ray://host:10001); default: a local Ray on this "
                        "machine's cores. On a cluster, --out must be a folder every node sees")
    p.add_argument("--cpus-per-trial", type=float, default=1, help="CPUs Ray reserves per trial (default: %(default)s)")
    p.add_argument("--gpus-per-trial", type=float, default=0, help="GPUs Ray reserves per trial (default: %(default)s)")
    p.add_argument("--max-retries", type=int, default=2,
                   help="reruns of a trial whose worker died or whose env process was lost; each resumes from "
                        "its checkpoint (default: %(default)s)")
    add_dataclass_args(p, RLConfig, skip=SWEEP_FIELDS, aliases=RL_ALIASES, choices=_rl_choices(),
                       presets={name: RLConfig.from_preset(name) for name in PRESETS})
    p.set_defaults(func=_cmd_sweep)


if __name__ == "__main__":
    sys.exit("train-policy, sweep and compare are subcommands of the one command line: "
             "drem-maniskill train-policy|sweep|compare ... (drem-maniskill --help)")
