"""``check-reward``: does a reward pay for the wrong thing? A short SAC run on it, then where its failures end.

A DREM reward can order an expert's episodes well and still pay a state the tree never held (a hand held in
front of the receptacle, a part pressed on the socket's face) almost what it pays the goal: a policy finds
that state and stays. This check runs SAC on the reward (the ``state`` preset, so only the reward is on
trial, not vision), rolls its policy out on held-out seeds and the scripted expert beside it, and reports:

* return against success: the policy's success rate, its mean progress ``R`` per step, the expert's;
* every failed episode's end: ``R`` over its last steps, and how far each of the task's moving objects
  (and the hand) is from where the expert leaves it on the same seed;
* return against success along the SAC run: each of its evaluations (``eval.csv``) as success rate and mean
  ``R`` per step; an evaluation without success whose policy is paid per step at least ``paid_fraction`` of
  what the expert is paid at its success is a paid evaluation (a policy that stays where it is paid);
* ``paid failures``: failed episodes of the final policy that end paid at least ``paid_fraction`` of the
  expert's end. The reward has an exploit when any evaluation was paid, or when paid failures are at least
  ``exploit_share`` of the episodes.

Rewards are reported as the paper's ``R`` (``drem_form="paper"``) whatever form the SAC run trained on.

With ``run`` the check trains nothing: it examines a finished ``train-policy`` run of any reward and preset (a
comparison's run whose return is high and success low), under that run's own reward and inputs.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Optional, Sequence

import numpy as np
import torch

from drem_maniskill.envs import check_env_id
from drem_maniskill.evaluate.probes import end_reward
from drem_maniskill.experts import get_policy, rollout
from drem_maniskill.rl.config import RLConfig
from drem_maniskill.utils.atomic import write_json
from drem_maniskill.utils.episodes import max_episode_steps

# The trainer and stable-baselines3 load inside the functions that run a check: the CLI imports CheckConfig to build
# its parser.
LAST_STEPS = 10  # a failure "ends" over this many steps: a policy that stays there, not one passing by


@dataclass
class CheckConfig:
    """What ``check-reward`` runs and how it judges."""

    task: str = "PegInHole-v1"
    """Env id the reward is for."""
    checkpoint: Optional[str] = None
    """The DREM checkpoint; None: the shipped rewards/<task>/drem.pt."""
    steps: int = 20_000
    """SAC env steps (the state preset)."""
    seed: int = 0
    """SAC's seed."""
    episodes: int = 10
    """Held-out episodes of the trained policy and of the expert."""
    eval_seed: int = 10_000
    """First held-out seed."""
    learning_starts: int = 1_000
    """SAC's random steps before its first update."""
    eval_every: int = 2_500
    """Env steps between SAC's own evaluations (its eval.csv)."""
    eval_episodes: int = 3
    """Episodes per SAC evaluation."""
    paid_fraction: float = 0.8
    """A failed episode is a paid failure when its end is paid at least this share of the expert's end."""
    exploit_share: float = 0.3
    """The reward has an exploit when paid failures are at least this share of the episodes."""
    out: Optional[str] = None
    """Output dir; None: outputs/check_reward/<task>/<checkpoint name> (``<run>/check`` with ``run``)."""
    run: Optional[str] = None
    """A finished ``train-policy`` run (any reward, any preset) to examine instead of training one: its
    ``config.json`` gives the task, the reward and the inputs, its last checkpoint the policy."""
    compare: Optional[str] = None
    """Another DREM checkpoint of the task: the report also gives what it pays where each episode (the policy's and
    the expert's) ends, on the same states (a reward that teaches against one that does not)."""

    def __post_init__(self):
        if self.steps <= self.learning_starts:
            raise ValueError(f"--steps ({self.steps}) must exceed --learning-starts ({self.learning_starts}): "
                             "SAC learns nothing before them")
        if self.episodes < 1:
            raise ValueError(f"--episodes must be at least 1, got {self.episodes}")


def policy_config(config: CheckConfig, checkpoint: Path, out: Path) -> RLConfig:
    """The SAC run of a check: the state preset on the drem reward paid by ``checkpoint``."""
    return RLConfig.from_preset("state", task=config.task, reward="drem", seed=config.seed, steps=config.steps,
                                learning_starts=config.learning_starts,
                                eval_every=min(config.eval_every, config.steps),
                                reward_checkpoint=str(checkpoint), out=str(out / "sac"),
                                eval_episodes=config.eval_episodes)


def moving_objects(env) -> dict:
    """``{name: position [3]}`` of the task's dynamic actors, the held part's tip in the socket's frame (our tasks,
    where the part is a link of the robot) and the hand (``tcp``), first env of the batch."""
    u = env.unwrapped
    out = {name: actor.pose.p[0].cpu().numpy() for name, actor in u.scene.actors.items()
           if getattr(actor, "px_body_type", "") == "dynamic"}
    if hasattr(u, "tip_pose_in_socket"):
        out["part tip"] = u.tip_pose_in_socket().p[0].cpu().numpy()
    out["tcp"] = u.agent.tcp.pose.p[0].cpu().numpy()
    return out


def task_measures(env) -> dict:
    """The task's own ``evaluate()`` numbers at this state, first env of the batch: every per-env scalar
    (an insertion's depth, radial offset and angle errors; a cube's distance to its goal), so a report says
    how a failure falls short in the task's terms."""
    out = {}
    for key, value in env.unwrapped.evaluate().items():
        if isinstance(value, torch.Tensor) and value.ndim == 1 and key != "success":
            out[key] = round(float(value[0]), 4)
    return out


def _episode_report(ep, objects: dict, expert_objects: Optional[dict], measures: Optional[dict] = None) -> dict:
    """One policy episode: success, R per step, R at its end (and the compared reward's), and (failed) where its
    objects are."""
    rewards = np.asarray(ep.rewards, dtype=float)
    row = dict(seed=ep.seed, success=bool(ep.success), mean_reward=float(rewards.mean()),
               end_reward=float(rewards[-LAST_STEPS:].mean()), **_compared_end(ep, LAST_STEPS))
    if not ep.success:
        if measures:
            row["task_measures"] = measures
        if expert_objects is not None:
            row["distance_from_expert_end"] = {k: round(float(np.linalg.norm(v - expert_objects[k])), 4)
                                               for k, v in objects.items() if k in expert_objects}
        else:
            row["position"] = {k: [round(float(x), 4) for x in v] for k, v in objects.items()}
    return row


def compared_reward(checkpoint: Optional[str], env) -> Optional[Callable]:
    """``measure`` for ``rollout`` that records what the DREM reward of ``checkpoint`` pays each step (``R``, as
    ``compare_reward``), or None without a checkpoint."""
    if checkpoint is None:
        return None
    from drem_maniskill.drem.reward import DREMReward

    other = DREMReward.from_checkpoint(checkpoint, env)

    def measure(env, obs, action, info) -> dict:
        return {"compare_reward": float(other.reward(env, None)[0])}

    return measure


def _compared_end(ep, last: int) -> dict:
    """``{"compare_end_reward": ...}``: the compared reward over the episode's last ``last`` steps (none without)."""
    values = ep.measures.get("compare_reward", [])
    return {"compare_end_reward": float(np.mean(values[-last:]))} if values else {}


def expert_ends(run: RLConfig, seeds: Sequence[int], compare: Optional[str] = None) -> Optional[dict]:
    """The scripted expert on ``seeds`` under the reward: ``R`` at its end and its objects there (and what the
    ``compare`` checkpoint pays there); None without one.

    Under a DREM reward the episode's steps skip it and ``R`` is read once, at the end (``probes.end_reward``): a
    step's reward renders the cameras, and only the last one is read.
    """
    from drem_maniskill.rl.run_env import make_eval_env

    env = make_eval_env(dataclasses.replace(run, action_scale=1.0, drem_form="paper"))
    try:
        try:
            expert = get_policy("expert", env, seed=0)
        except ValueError:
            return None
        measure = compared_reward(compare, env)
        horizon = max_episode_steps(run.task)
        ends = {}
        for seed in seeds:
            end, ep = end_reward(env, expert, int(seed), horizon, stop_on_success=True)
            compared = measure(env, None, None, None)["compare_reward"] if measure else None
            ends[int(seed)] = dict(success=bool(ep.success), end_reward=float(end), objects=moving_objects(env),
                                   **({} if compared is None else {"compare_end_reward": compared}))
        return ends
    finally:
        env.close()


def given_run(config: CheckConfig) -> tuple:
    """``(its policy, its DREM checkpoint or None, the report's folder)`` of ``config.run``, a finished run."""
    from drem_maniskill.rl.rewards import reward_checkpoint, reward_spec
    from drem_maniskill.rl.run_policy import load_policy

    policy = load_policy(config.run)
    run = policy.config
    learned = policy.checkpoint / f"{run.reward}.pt"
    spec = reward_spec(run.reward)
    if spec.checkpoint and spec.learner is not None and learned.is_file():
        # A DREM reward fine-tuned during the run: judged as the drem reward of the checkpoint it ended on.
        ended_on = torch.load(learned, weights_only=True)["checkpoint"]
        run = dataclasses.replace(run, reward="drem", reward_checkpoint=ended_on)
        policy = dataclasses.replace(policy, config=run)
    out = Path(config.out) if config.out else Path(config.run) / "check"
    return policy, reward_checkpoint(run.reward, run.task, run.reward_checkpoint), out


def trained_run(config: CheckConfig) -> tuple:
    """``(run config, its DREM checkpoint, the report's folder, its steps)`` of a SAC run trained (or resumed) on the
    reward of ``config.checkpoint``."""
    from drem_maniskill.drem.checkpoint import resolve_checkpoint
    from drem_maniskill.rl.train_policy import train_policy

    task = check_env_id(config.task)
    checkpoint = resolve_checkpoint(task, config.checkpoint)
    out = Path(config.out) if config.out else Path("outputs/check_reward") / task / checkpoint.stem
    run = policy_config(config, checkpoint, out)
    return run, checkpoint, out, train_policy(run)["steps"]


def run_curve(run: RLConfig) -> list:
    """The SAC run's evaluations as ``{steps, success_rate, reward_per_step}`` (``R``, whatever form it trained on).

    Evaluation episodes run the whole horizon, so a return is ``horizon`` rewards: ``R - 1`` each in the
    shifted form.
    """
    from drem_maniskill.rl.rewards import reward_spec
    from drem_maniskill.rl.train_policy import read_eval_csv

    horizon = max_episode_steps(run.task)
    shift = 1.0 if reward_spec(run.reward).checkpoint and run.drem_form_used == "shifted" else 0.0
    return [dict(steps=int(r["steps"]), success_rate=float(r["success_rate"]),
                 reward_per_step=round(float(r["mean_return"]) / horizon + shift, 4))
            for r in read_eval_csv(run.run_dir / "eval.csv")]


def judge(rows: list, expert: Optional[dict], config: CheckConfig, curve: Sequence[dict] = ()) -> dict:
    """Return against success, and whether the failures are paid like the expert's success."""
    succeeded = [e["end_reward"] for e in (expert or {}).values() if e["success"]]
    expert_end = float(np.mean(succeeded)) if succeeded else None
    failed = [r for r in rows if not r["success"]]
    threshold = config.paid_fraction * expert_end if expert_end is not None else None
    paid = [r for r in failed if threshold is not None and r["end_reward"] >= threshold]
    paid_evals = [c["steps"] for c in curve
                  if threshold is not None and c["success_rate"] == 0 and c["reward_per_step"] >= threshold]
    share = len(paid) / len(rows)
    return dict(
        success_rate=float(np.mean([r["success"] for r in rows])),
        mean_reward_per_step=float(np.mean([r["mean_reward"] for r in rows])),
        failed_end_reward=float(np.mean([r["end_reward"] for r in failed])) if failed else None,
        expert_success_rate=float(np.mean([e["success"] for e in expert.values()])) if expert else None,
        expert_end_reward=expert_end,
        paid_threshold=threshold,
        paid_failures=len(paid),
        paid_failure_share=share,
        paid_evaluations=paid_evals,
        exploit=bool(paid_evals) or bool(threshold is not None and paid and share >= config.exploit_share),
        **({"compare": compared_ends(rows, expert, config.compare)} if config.compare else {}),
    )


def compared_ends(rows: list, expert: Optional[dict], checkpoint: str) -> dict:
    """What the compared reward pays where the failed and the successful episodes end, and at the expert's end."""

    def mean(values):
        values = [v for v in values if v is not None]
        return float(np.mean(values)) if values else None

    return dict(checkpoint=checkpoint,
                failed_end_reward=mean(r.get("compare_end_reward") for r in rows if not r["success"]),
                success_end_reward=mean(r.get("compare_end_reward") for r in rows if r["success"]),
                expert_end_reward=mean(e.get("compare_end_reward") for e in (expert or {}).values() if e["success"]))


def check_reward(config: CheckConfig) -> dict:
    """Run the check (resuming a SAC run it already started) and write ``report.json``; returns the report."""
    from drem_maniskill.rl.run_env import make_eval_env
    from drem_maniskill.rl.run_policy import load_policy
    from drem_maniskill.rl.train_policy import file_sha256, shown_path

    if config.run:
        policy, checkpoint, out = given_run(config)
        run = policy.config
        steps = run_curve(run)[-1]["steps"]
    else:
        run, checkpoint, out, steps = trained_run(config)
        policy = load_policy(run.run_dir)
    task = run.task if config.run else check_env_id(config.task)
    out.mkdir(parents=True, exist_ok=True)
    seeds = [config.eval_seed + i for i in range(config.episodes)]
    expert = expert_ends(run, seeds, config.compare)
    act = policy.act()
    env = make_eval_env(dataclasses.replace(run, drem_form="paper"))
    rows = []
    try:
        measure = compared_reward(config.compare, env)
        for seed in seeds:
            ep = rollout(env, act, seed, max_episode_steps(task), stop_on_success=False, measure=measure)
            rows.append(_episode_report(ep, moving_objects(env), expert[seed]["objects"] if expert else None,
                                        task_measures(env)))
    finally:
        env.close()
    curve = run_curve(run)
    report = dict(task=task, reward=run.reward, out=shown_path(out),
                  checkpoint=None if checkpoint is None else shown_path(checkpoint),
                  sha256=None if checkpoint is None else file_sha256(checkpoint),
                  sac=dict(steps=steps, preset=run.preset, seed=run.seed, run_dir=shown_path(run.run_dir), curve=curve),
                  verdict=judge(rows, expert, config, curve), episodes=rows, config=dataclasses.asdict(config))
    write_json(out / "report.json", report)
    return report


def markdown_table(report: dict) -> str:
    """The report as a model card's table (every number read from ``report.json``)."""
    v, sac = report["verdict"], report["sac"]

    def fmt(x):
        return "n/a" if x is None else f"{x:.3f}"

    curve = "; ".join(f"{c['steps']:,}: {c['success_rate']:.0%}, {c['reward_per_step']:.2f}" for c in sac["curve"])
    seeds = [e["seed"] for e in report["episodes"]]
    rows = [
        (f"SAC ({sac.get('preset', 'state')} preset, seed {sac.get('seed', report['config']['seed'])}) along its run: "
         "steps: success, R per step", curve),
        (f"its final policy on held-out seeds {seeds[0]}-{seeds[-1]}: success, mean R per step",
         f"{v['success_rate']:.0%}, {v['mean_reward_per_step']:.3f}"),
        ("R over the last steps of its failed episodes", fmt(v["failed_end_reward"])),
        ("scripted expert on the same seeds: success, R at its end",
         f"{'n/a' if v['expert_success_rate'] is None else format(v['expert_success_rate'], '.0%')}, "
         f"{fmt(v['expert_end_reward'])}"),
        (f"paid failures (end R >= {fmt(v['paid_threshold'])}, {report['config']['paid_fraction']:g} x the expert's)",
         f"{v['paid_failures']} of {len(report['episodes'])}"),
        ("evaluations paid like success without any", ", ".join(f"{s:,}" for s in v["paid_evaluations"]) or "none"),
        ("verdict", "EXPLOIT: the reward pays failures like success" if v["exploit"] else "no exploit found"),
    ]
    return "\n".join(["| check-reward | value |", "| --- | --- |", *(f"| {a} | {b} |" for a, b in rows)])


def summary_lines(report: dict) -> list:
    """The report in a few lines, as the command prints it."""
    v = report["verdict"]

    def fmt(x):
        return "n/a" if x is None else f"{x:.3f}"

    curve = "; ".join(f"{c['steps']}: success {c['success_rate']:.2f}, R {c['reward_per_step']:.3f}"
                      for c in report["sac"]["curve"])
    sac = report["sac"]
    lines = [f"{report['task']}: {report.get('reward', 'drem')} ({report['checkpoint'] or 'no checkpoint'}) after "
             f"{sac['steps']} SAC steps ({sac.get('preset', 'state')} preset)",
             f"  along the run (steps: success, mean R per step): {curve}",
             f"  policy: success {v['success_rate']:.2f}, mean R per step {v['mean_reward_per_step']:.3f}; "
             f"failed episodes end at R {fmt(v['failed_end_reward'])}",
             f"  expert: success {fmt(v['expert_success_rate'])}, R at its end {fmt(v['expert_end_reward'])}",
             f"  paid failures (end R >= {fmt(v['paid_threshold'])}): {v['paid_failures']} of "
             f"{len(report['episodes'])} episodes"]
    for row in report["episodes"]:
        if not row["success"]:
            where = row.get("distance_from_expert_end") or row.get("position")
            lines.append(f"    seed {row['seed']}: ends at R {row['end_reward']:.3f}; "
                         + ", ".join(f"{k} {v} m from the expert's end" if "distance_from_expert_end" in row
                                     else f"{k} at {v}" for k, v in where.items()))
            if row.get("task_measures"):
                lines.append("      the task's evaluate(): "
                             + ", ".join(f"{k} {v:g}" for k, v in row["task_measures"].items()))
    if v["paid_evaluations"]:
        lines.append(f"  paid without success at steps {v['paid_evaluations']}")
    if v.get("compare"):
        c = v["compare"]
        lines.append(f"  under {c['checkpoint']}: failed episodes end at R {fmt(c['failed_end_reward'])}, successful "
                     f"ones at {fmt(c['success_end_reward'])}, the expert's end {fmt(c['expert_end_reward'])}")
    lines.append("  EXPLOIT: the reward pays failures like success" if v["exploit"]
                 else "  no exploit found")
    return lines
