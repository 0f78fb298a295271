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

    # The clear errors before anything heavy loads.
    check_env_id(args.task)
    reward_spec(args.reward)
    algo_spec(args.algo)
    overrides = {k: v for k, v in dict(steps=args.steps, out=args.out, eval_every=args.eval_every,
                                       eval_episodes=args.eval_episodes, threads=args.threads, num_envs=args.num_envs,
                                       sim_backend=args.sim_backend, learning_starts=args.learning_starts,
                                       batch_size=args.batch_size, device=args.device,
                                       reward_checkpoint=args.reward_checkpoint,
                                       terminate_on_success=args.terminate_on_success, obs_norm=args.obs_norm,
                                       action_scale=args.action_scale, gamma=args.gamma,
                                       gradient_steps=args.gradient_steps, train_freq=args.train_freq, net_arch=args.net_arch, train_bf16=args.bf16, overlap_env=args.overlap_env, drem_form=args.drem_form).items() if v is not None}
    config = RLConfig.preset(args.preset, task=args.task, reward=args.reward, algo=args.algo, seed=args.seed, **overrides)
    print(f"policy config: {json.dumps(config.to_dict())}")
    result = train_policy(config)
    print(json.dumps(result, indent=2))


def _cmd_compare(args) -> None:
    from drem_maniskill.rl.compare import compare_runs

    result = compare_runs(args.runs, args.out, band=args.band)
    print(open(result["markdown"]).read())
    print(f"plot: {result['png']}, numbers: {result['json']}")


def add_subcommands(sub) -> None:
    """Add ``train-policy`` and ``compare`` to an argparse subparsers object (here and in ``drem-maniskill``)."""
    from drem_maniskill.drem.reward import DREM_FORMS
    from drem_maniskill.rl.config import PRESETS
    from drem_maniskill.rl.rewards import REWARDS

    p = sub.add_parser("train-policy", help="SAC on a task with a reward chosen by name; rerun to resume")
    p.add_argument("--task", default="PegInHole-v1", help="env id (default: %(default)s)")
    # No argparse choices: reward_spec's error lists them and says what was asked for.
    p.add_argument("--reward", default="drem", help=f"one of {', '.join(REWARDS)} (default: %(default)s)")
    p.add_argument("--algo", default="sac", help="RL algorithm, a name of rl.algos.ALGOS (default: %(default)s)")
    p.add_argument("--seed", type=int, default=0, help="training seed (default: %(default)s)")
    p.add_argument("--steps", type=int, help="env steps (default: the preset's; state 50000, light 20000, paper 150000)")
    p.add_argument("--preset", default="light", choices=list(PRESETS), help="state: no images, for reward studies; light: images on this CPU; paper: the paper's obs, GPU")
    p.add_argument("--out", help="run dir (default: outputs/rl/<task>/<reward>/seed<S>)")
    p.add_argument("--eval-every", type=int, help="steps between evaluations and checkpoints")
    p.add_argument("--eval-episodes", type=int, help="held-out seeds per evaluation (from 10000)")
    p.add_argument("--reward-checkpoint", help="drem rewards: this DREM checkpoint instead of the shipped rewards/<task>/drem.pt")
    p.add_argument("--terminate-on-success", action=argparse.BooleanOptionalAction, default=None,
                   help="end a training episode at its first success (default: the preset's; on for state and light, off for paper: episodes run to the time limit)")
    p.add_argument("--drem-form", choices=list(DREM_FORMS),
                   help="drem rewards: paper pays R, shifted R - 1 (never positive) (default: shifted where episodes end at success, else paper)")
    p.add_argument("--obs-norm", nargs="*", choices=["state", "ft"],
                   help="normalise these policy inputs by running statistics (default: the preset's; none: --obs-norm)")
    p.add_argument("--action-scale", type=float, help="the policy's full range as a fraction of the controller's (default: the preset's; state and light 0.5, paper 1)")
    p.add_argument("--gamma", type=float, help="discount (default: the preset's, 0.95)")
    p.add_argument("--gradient-steps", type=int, help="SAC gradient steps per --train-freq env steps (default: 1)")
    p.add_argument("--train-freq", type=int,
                   help="env steps between SAC updates; the update ratio is gradient-steps / train-freq (default: the preset's)")
    p.add_argument("--net-arch", type=int, nargs="+", help="hidden layer widths of actor and critics (default: the preset's)")
    p.add_argument("--bf16", action=argparse.BooleanOptionalAction, default=None,
                   help="SAC's gradient step under bfloat16 autocast (default: the preset's; see docs/rl.md, Speed)")
    p.add_argument("--overlap-env", action=argparse.BooleanOptionalAction, default=None,
                   help="step the env in a child process while SAC's gradient step runs here (default: the preset's; "
                        "not with vice; docs/rl.md, Speed)")
    p.add_argument("--learning-starts", type=int)
    p.add_argument("--batch-size", type=int)
    p.add_argument("--num-envs", type=int, help="parallel envs (GPU sim)")
    p.add_argument("--sim-backend", help="cpu or gpu")
    p.add_argument("--device", help="torch device of SAC (default: auto)")
    p.add_argument("--threads", type=int, help="torch CPU threads")
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
