"""``drem-maniskill``: one subcommand per stage, each a thin shell over a library function."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from drem_maniskill.utils.cli import run_command


def _cmd_demo(args) -> None:
    from drem_maniskill.demo import run_demo

    summary = run_demo(out=args.out, tasks=args.tasks, scale=args.scale, drem=not args.no_drem)
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
        raise ValueError(f"--env-kwargs must be a JSON object, e.g. '{{\"sim_backend\": \"cpu\"}}': {err}") from err
    result = record_expert(args.task, args.out, seeds=seeds, obs_mode=args.obs_mode, name=args.name,
                           save_video=args.video, env_kwargs=env_kwargs, descent_step=args.descent_step,
                           descend_from=args.descend_from)
    print(json.dumps({"trajectory": result.h5_path, "metadata": result.json_path, "success_rate": result.success_rate,
                      "lengths": result.lengths}, indent=2))


def _cmd_scripted_success(args) -> None:
    from drem_maniskill.experts import success_rate

    result = success_rate(args.task, args.policy, seeds=range(args.seed, args.seed + args.episodes))
    print(json.dumps(result, indent=2))


def _cmd_sample(args) -> None:
    from drem_maniskill.pipeline import SamplerConfig, backward_sample
    from drem_maniskill.pipeline.dataset import tree_report
    from drem_maniskill.utils.config_cli import apply_overrides, overrides_from_args

    config = apply_overrides(SamplerConfig.preset(args.preset), overrides_from_args(args, SamplerConfig))
    print(f"sampler config: {config}")
    path = backward_sample(args.expert, args.out, config)
    print(f"progress tree: {path}")
    print(f"regions around the opening: {json.dumps(tree_report(path))}")


def _cmd_train_reward(args) -> None:
    from drem_maniskill.pipeline.dataset import dataset_modalities
    from drem_maniskill.pipeline.train_reward import TrainConfig, train_reward
    from drem_maniskill.utils.config_cli import apply_overrides, overrides_from_args

    overrides = overrides_from_args(args, TrainConfig)
    # Default: every modality the tree holds (a stock ManiSkill task has no F/T sensor).
    model = overrides.setdefault("model", {})
    model.setdefault("modalities", dataset_modalities(args.dataset))
    config = apply_overrides(TrainConfig.preset(args.preset), overrides)
    print(f"training config: {config}")
    path = train_reward(args.dataset, args.out, config)
    print(f"reward checkpoint: {path}")


def _cmd_build_reward(args) -> None:
    from drem_maniskill.pipeline.build_reward import build_reward

    path = build_reward(args.task, scale=args.scale, out=args.out, recipe=args.recipe, publish=args.publish)
    print(f"reward: {path}")


def _cmd_calibrate_support(args) -> None:
    from drem_maniskill.pipeline.support import calibrate_support

    result = calibrate_support(args.checkpoint, args.dataset, args.out)
    print(json.dumps({k: result[k] for k in ("nodes", "quantile", "tau", "max", "median")}, indent=2))


def _cmd_examine(args) -> None:
    from drem_maniskill.evaluate.examine import examine

    result = examine(args.task, args.checkpoint, seeds=range(args.seed, args.seed + args.episodes), out_dir=args.out)
    keys = ("value_order_spearman", "final_reward_auroc", "random_mean_reward", "search_fail_contact_loss",
            "search_fail_first_contact_loss", "contact_plateau", "colour_spread", "held_positions",
            "inserted_reward_std",
            "success_rate", "spearman_with_normalized_dense", "spearman_with_insertion_depth",
            "spearman_with_normalized_dense_expert")
    print(json.dumps({k: result.get(k) for k in keys}, indent=2))
    print(f"plot: {args.out}/examination.png, numbers: {args.out}/quality.json")


def _cmd_run_script(args) -> None:
    from drem_maniskill.launcher import run_module, run_script

    extra = args.args[1:] if args.args[:1] == ["--"] else args.args
    (run_module if args.module else run_script)(args.script, extra)


# Shorter flags for the training settings set most often, each beside its field's own flag.
TRAIN_ALIASES = {"pairs_per_batch": ["--pairs"], "model.modalities": ["--modalities"],
                 "model.image_size": ["--image-size"]}
TRAIN_CHOICES = {"model.modalities": ["fixed", "wrist", "ft", "poses"]}
# Preset names the help shows defaults for; an unknown name is refused by the config's own ``preset``.
PRESET_NAMES = ("paper", "quick", "tiny")


def _presets(cls) -> dict:
    """``{name: cls.preset(name)}`` for the names of ``PRESET_NAMES`` that ``cls`` has."""
    presets = {}
    for name in PRESET_NAMES:
        try:
            presets[name] = cls.preset(name)
        except ValueError:
            continue
    return presets


def _add_demo(sub) -> None:
    from drem_maniskill.envs import TASKS

    p = sub.add_parser("demo", help="build-reward at a small scale on each of our tasks, with plots of the expert demo",
                       description="For each task: its recipe's expert demo drawn (camera strips, the wrist F/T), then "
                                   "build-reward at the recipe's demo scale into OUT/TASK (rerun to resume), and a "
                                   "summary.json of the demo and the examination's measures.")
    p.add_argument("--out", default="outputs/demo", help="output folder (default: %(default)s)")
    p.add_argument("--tasks", nargs="+", default=list(TASKS), help="task ids (default: all of ours, %(default)s)")
    p.add_argument("--scale", default="demo", choices=["demo", "tiny"], help="demo: minutes here; tiny: for CI")
    p.add_argument("--no-drem", action="store_true", help="only the expert demo and its plots")
    p.set_defaults(func=_cmd_demo)


def _add_record_expert(sub) -> None:
    p = sub.add_parser("record-expert", help="record scripted-expert episodes in ManiSkill's .h5/.json format")
    p.add_argument("--task", default="PegInHole-v1", help="env id (default: %(default)s)")
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
                        "smaller gives the progress tree more depths inside it (docs/experiment-log.md)")
    p.add_argument("--descend-from", type=float,
                   help="our tasks: metres above the socket's top face the aligned expert starts its slow descent "
                        "(default: wherever it aligned, often 2 cm up); above it, it approaches the pre-insertion "
                        "point 6 mm above the opening at its approach speed, so fewer of the demo's steps hover "
                        "(docs/experiment-log.md)")
    p.set_defaults(func=_cmd_record_expert)


def _add_scripted_success(sub) -> None:
    p = sub.add_parser("scripted-success", help="success rate of a scripted policy over many seeds")
    p.add_argument("--task", default="PegInHole-v1", help="env id (default: %(default)s)")
    p.add_argument("--policy", default="expert", help="expert, direct_success, align_success, search_fail, random")
    p.add_argument("--episodes", type=int, default=100, help="number of seeds (default: %(default)s)")
    p.add_argument("--seed", type=int, default=0, help="first seed (default: %(default)s)")
    p.set_defaults(func=_cmd_scripted_success)


def _add_examine(sub) -> None:
    p = sub.add_parser("examine", help="examine a DREM reward with the four scripted policies; plot and JSON")
    p.add_argument("--task", default="PegInHole-v1", help="env id (default: %(default)s)")
    p.add_argument("--checkpoint", required=True, help="reward checkpoint (.pt)")
    p.add_argument("--out", default="outputs/examination", help="output folder (default: %(default)s)")
    p.add_argument("--episodes", type=int, default=20, help="seeds per policy (default: %(default)s)")
    p.add_argument("--seed", type=int, default=0, help="first seed; keep clear of the expert's (default: %(default)s)")
    p.set_defaults(func=_cmd_examine)


def _add_sample(sub) -> None:
    from drem_maniskill.pipeline import SamplerConfig
    from drem_maniskill.utils.config_cli import add_dataclass_args

    p = sub.add_parser("sample", help="backward sampling: build the task progress tree from an expert trajectory",
                       description="Backward sampling: the task progress tree from an expert trajectory. Every flag "
                                   "but --expert, --out and --preset sets the SamplerConfig field of its name, on "
                                   "top of the preset.")
    p.add_argument("--expert", required=True, help="expert trajectory .h5 (RecordEpisode format, .json beside it)")
    p.add_argument("--out", default="outputs/tree.h5",
                   help="dataset to write (default: %(default)s); resumes from <out>.partial")
    p.add_argument("--preset", default="paper",
                   help=f"sampler preset, one of {', '.join(_presets(SamplerConfig))} (default: %(default)s)")
    add_dataclass_args(p, SamplerConfig, presets=_presets(SamplerConfig))
    p.set_defaults(func=_cmd_sample)


def _add_train_reward(sub) -> None:
    from drem_maniskill.pipeline.train_reward import TrainConfig
    from drem_maniskill.utils.config_cli import add_dataclass_args

    p = sub.add_parser("train-reward", help="train the DREM progress model on a progress tree",
                       description="Train the DREM progress model on a progress tree. Every flag but --dataset, "
                                   "--out and --preset sets the TrainConfig field of its name (--model-*: its "
                                   "ModelConfig), on top of the preset; --model-modalities defaults to every "
                                   "modality the tree holds.")
    p.add_argument("--dataset", required=True, help="progress tree .h5 from `sample`")
    p.add_argument("--out", default="outputs/reward", help="output folder: drem.pt, tb/, train_state.pt (resume)")
    p.add_argument("--preset", default="paper",
                   help=f"training preset, one of {', '.join(_presets(TrainConfig))}: paper: 20k iterations at "
                        "128 px; quick and tiny: CPU-sized (default: %(default)s)")
    add_dataclass_args(p, TrainConfig, aliases=TRAIN_ALIASES, choices=TRAIN_CHOICES, presets=_presets(TrainConfig))
    p.set_defaults(func=_cmd_train_reward)


def _add_build_reward(sub) -> None:
    p = sub.add_parser("build-reward", help="one task's DREM reward from its recipe: record, sample, train, "
                                            "examine, calibrate; each stage resumes",
                       description="One task's DREM reward from its recipe, each stage resuming, the products "
                                   "(drem.pt, quality.json, ...) under the work folder; --publish copies them into "
                                   "the shipped rewards/<task>/.")
    p.add_argument("--task", required=True, help="env id whose recipe (tasks/<task>/recipe.toml) to run")
    p.add_argument("--scale", default="full", choices=["tiny", "demo", "full"],
                   help="tiny: a few minutes, for tests; demo: about 2 minutes a task; full: the recipe as shipped, "
                        "hours (default: %(default)s)")
    p.add_argument("--out", help="work folder (default: outputs/build_reward/<task>/<scale>)")
    p.add_argument("--recipe", help="recipe file instead of the task's own")
    p.add_argument("--publish", action="store_true",
                   help="full scale: copy the products into the shipped rewards/<task>/, naming each file replaced")
    p.set_defaults(func=_cmd_build_reward)


def _cmd_check_reward(args) -> None:
    from drem_maniskill.evaluate.check_reward import CheckConfig, check_reward, summary_lines
    from drem_maniskill.utils.config_cli import apply_overrides, overrides_from_args

    report = check_reward(apply_overrides(CheckConfig(), overrides_from_args(args, CheckConfig)))
    print("\n".join(summary_lines(report)))
    print(f"report: {Path(report['out']) / 'report.json'}")


def _add_check_reward(sub) -> None:
    from drem_maniskill.evaluate.check_reward import CheckConfig
    from drem_maniskill.utils.config_cli import add_dataclass_args

    p = sub.add_parser("check-reward", help="does a reward pay for the wrong thing? a short SAC run, then where its "
                                            "failures end and what the reward pays there",
                       description="A short state-preset SAC run on a DREM reward; its policy and the scripted "
                                   "expert on held-out seeds; return against success, where failed episodes end "
                                   "(each moving object's distance from the expert's end) and what the reward pays "
                                   "there. Rerun to resume. Every flag sets the CheckConfig field of its name.")
    add_dataclass_args(p, CheckConfig)
    p.set_defaults(func=_cmd_check_reward)


def _add_calibrate_support(sub) -> None:
    p = sub.add_parser("calibrate-support", help="tree nodes' reconstruction errors for the drem-guarded reward")
    p.add_argument("--checkpoint", required=True, help="a DREM checkpoint (drem.pt)")
    p.add_argument("--dataset", required=True, help="the progress tree it was trained on")
    p.add_argument("--out", required=True, help="support.json to write (rewards/<task>/support.json for drem-guarded)")
    p.set_defaults(func=_cmd_calibrate_support)


def _add_run_script(sub) -> None:
    p = sub.add_parser("run-script", help="run a ManiSkill script (e.g. ppo_cpu.py) with our env ids registered")
    p.add_argument("script", help="the script, e.g. ManiSkill's examples/baselines/ppo/ppo_cpu.py (with -m: a module)")
    p.add_argument("-m", "--module", action="store_true",
                   help="SCRIPT is a module, run as `python -m`, e.g. mani_skill.examples.benchmarking.gpu_sim")
    p.add_argument("args", nargs=argparse.REMAINDER, help="-- then the script's own arguments")
    p.set_defaults(func=_cmd_run_script)


def build_parser() -> argparse.ArgumentParser:
    """The argument parser of the ``drem-maniskill`` command."""
    from drem_maniskill.rl.__main__ import add_subcommands

    parser = argparse.ArgumentParser(prog="drem-maniskill", description=__doc__)
    sub = parser.add_subparsers(dest="command", required=True)
    for add in (_add_demo, _add_record_expert, _add_scripted_success, _add_examine, _add_sample, _add_train_reward,
                _add_build_reward, _add_check_reward, _add_calibrate_support):
        add(sub)
    add_subcommands(sub)  # train-policy, sweep, compare (drem_maniskill/rl, docs/rl.md)
    _add_run_script(sub)
    return parser


def main(argv=None) -> int:
    """Entry point of the ``drem-maniskill`` console script."""
    args = build_parser().parse_args(argv)
    from drem_maniskill.envs import check_env_id  # registers the tasks

    def check_tasks(args) -> None:
        """Refuse an unknown task id here, naming the ids we know, rather than deep inside gymnasium."""
        for task in [getattr(args, "task", None), *(getattr(args, "tasks", None) or [])]:
            if task is not None:
                check_env_id(task)

    return run_command("drem-maniskill", args, check_tasks)


if __name__ == "__main__":
    sys.exit(main())
