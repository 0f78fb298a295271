"""``drem-maniskill sweep``: a grid of ``train-policy`` runs (tasks x rewards x seeds x presets) on Ray.

Each trial is one ``train_policy`` run in ``<out>/<task>/<reward>/seed<S>`` (with more than one preset
``<out>/<preset>/<task>/<reward>/seed<S>``): the folders ``compare`` reads. Ray runs them on this
machine (``ray.init`` with its cores) or on a running cluster (``--address``), each with its CPU and
GPU share. Rerunning the same command resumes: a run already at the requested steps is skipped
without a trial, an interrupted one is rerun on its folder and continues from its checkpoint.

Why Ray core tasks and not Ray Tune: a trial here is one fixed run, with no search space, no
scheduler that stops or mutates trials, and its own checkpoints and resume in its own folder.
Tune would add a second layer of all three (its experiment folder under ``~/ray_results``, its
trial checkpoints, its restore) that would have to be kept in step with ``train_policy``'s, and
``ray[tune]``'s extra dependencies. A core task (``@ray.remote(num_cpus, num_gpus, max_retries,
retry_exceptions)``) gives what the grid needs: Ray's scheduling by resources, on one machine or a
cluster, and a rerun of a trial whose worker or node died; that rerun resumes from the checkpoint.
Each trial runs in a worker process of its own (``max_calls=1``), so no state of one run
(SAPIEN's, torch's, the redirected output) reaches the next.
"""

from __future__ import annotations

import json
import os
import sys
import time
from pathlib import Path
from typing import Iterable, Optional, Sequence

from drem_maniskill.rl.config import RLConfig

# RLConfig fields the sweep sets per trial; every other train-policy flag passes through to every trial.
SWEEP_FIELDS = ("preset", "task", "reward", "seed", "out", "steps")
# A lost env child process (its pipe closed under the run) is worth a rerun from the checkpoint; an error of
# the run itself (a bad option, a changed reward checkpoint) would fail the same way again.
RETRY_EXCEPTIONS = [EOFError, BrokenPipeError, ConnectionResetError]
# The torch and OpenMP threads of a trial yield their core when idle, as the env and SAC steps alternate.
TRIAL_ENV = {"OMP_WAIT_POLICY": "PASSIVE"}
INSTALL_HINT = "the sweep runs on Ray: pip install drem-maniskill[sweep] (or pip install 'ray>=2.9')"


def _unique(values: Iterable) -> list:
    """``values`` without repeats, in their order."""
    return list(dict.fromkeys(values))


def trial_dir(out, preset: str, task: str, reward: str, seed: int, nest_preset: bool = False) -> Path:
    """The run folder of one trial: ``<out>[/<preset>]/<task>/<reward>/seed<S>``."""
    root = Path(out) / preset if nest_preset else Path(out)
    return root / task / reward / f"seed{seed}"


def trial_config(preset: str, task: str, reward: str, seed: int, steps: int, out, overrides: Optional[dict] = None,
                 nest_preset: bool = False) -> RLConfig:
    """The RLConfig of one trial: the preset, the given train-policy flags, then its task, reward, seed and folder."""
    from drem_maniskill.utils.config_cli import apply_overrides

    config = apply_overrides(RLConfig.from_preset(preset), dict(overrides or {}))
    run_dir = trial_dir(out, preset, task, reward, seed, nest_preset)
    return apply_overrides(config, dict(task=task, reward=reward, seed=int(seed), steps=int(steps), out=str(run_dir)))


def check_grid(tasks: Sequence[str], rewards: Sequence[str], presets: Sequence[str]) -> None:
    """A ValueError naming the first unknown preset, task or reward, or a reward that does not fit a task."""
    from drem_maniskill.envs import check_env_id
    from drem_maniskill.rl.rewards import reward_spec, supported_rewards

    for preset in presets:
        RLConfig.from_preset(preset)
    for task in tasks:
        check_env_id(task)
    for reward in rewards:
        spec = reward_spec(reward)
        for task in tasks:
            if not spec.supports(task):
                raise ValueError(f"reward {reward!r} does not fit {task}; its rewards: {supported_rewards(task)}")


def plan_trials(tasks: Sequence[str], rewards: Sequence[str], seeds: Sequence[int], steps: int, out,
                presets: Sequence[str] = ("light",), overrides: Optional[dict] = None) -> list:
    """Every trial's RLConfig, checked before any runs; by preset, seed, task, reward (every task's and reward's seed 0
    first, so a grid cut short still compares every reward on every task)."""
    tasks, rewards, seeds, presets = _unique(tasks), _unique(rewards), _unique(int(s) for s in seeds), _unique(presets)
    check_grid(tasks, rewards, presets)
    if int(steps) <= 0:
        raise ValueError(f"--steps must be positive, got {steps}")
    nest = len(presets) > 1
    return [trial_config(preset, task, reward, seed, steps, out, overrides, nest)
            for preset in presets for seed in seeds for task in tasks for reward in rewards]


def configs_from_args(args) -> list:
    """The trials of a parsed ``sweep`` command line (its parser: ``rl.__main__.add_subcommands``)."""
    from drem_maniskill.utils.config_cli import overrides_from_args

    overrides = overrides_from_args(args, RLConfig, skip=SWEEP_FIELDS)
    return plan_trials(args.tasks, args.rewards, args.seeds, args.steps, args.out, args.presets, overrides)


def label(config: RLConfig) -> str:
    """How progress lines and log files name a trial: ``<preset> <task> <reward> seed<S>``."""
    return f"{config.preset} {config.task} {config.reward} seed{config.seed}"


def run_progress(config: RLConfig) -> tuple:
    """``(steps done, last eval row or None)``: the lower of the last checkpoint's step and eval.csv's last row.

    A run kept without its checkpoints (its ``config.json`` and ``eval.csv``, as results are committed) counts
    as done to its last evaluation when it reached the config's steps with the same settings, else as not begun.
    """
    from drem_maniskill.rl.train_policy import _check_resumable, read_eval_csv

    latest = config.run_dir / "checkpoints" / "latest.json"
    rows = read_eval_csv(config.run_dir / "eval.csv")
    if not rows:
        return 0, None
    if latest.exists():
        return min(int(json.loads(latest.read_text())["step"]), rows[-1]["steps"]), rows[-1]
    saved = config.run_dir / "config.json"
    if rows[-1]["steps"] < config.steps or not saved.exists():
        return 0, None
    _check_resumable(RLConfig.load(saved), config)
    return rows[-1]["steps"], rows[-1]


def _success(row: Optional[dict]) -> str:
    return "no evaluation" if row is None else f"success {row['success_rate']:.2f} at {int(row['steps'])} steps"


def split_finished(configs: Sequence[RLConfig]) -> tuple:
    """``(to run, finished)``; a ValueError when a folder holds a run of another config (before any trial starts)."""
    from drem_maniskill.rl.train_policy import check_resumable

    todo, finished = [], []
    for config in configs:
        check_resumable(config)
        done, row = run_progress(config)
        if done >= config.steps:
            finished.append(dict(trial=label(config), run_dir=str(config.run_dir), status="skipped", last_eval=row))
        else:
            todo.append(config)
    return todo, finished


def import_ray():
    """The ``ray`` module, or an ImportError that says how to install it."""
    try:
        import ray
    except ImportError as err:
        raise ImportError(f"{INSTALL_HINT} ({err})") from err
    return ray


def report_start(queue, item) -> None:
    """Put ``item`` on the sweep's start queue without waiting for it.

    A task blocked in ``ray.get`` (as ``Queue.put`` is) lends its CPU back to Ray, which then starts one
    trial more than the cores allow; a call that is not waited on keeps the trial's share.
    """
    if queue is not None:
        queue.actor.put_nowait.remote(item)


def run_trial(config: dict, log: str, cwd: str, queue=None) -> dict:
    """One trial in a Ray worker: ``train_policy`` with its output in ``log``; returns steps and last evaluation."""
    import traceback

    if os.path.isdir(cwd):
        os.chdir(cwd)  # relative --out and checkpoint paths mean what they meant to the sweep's command
    config = RLConfig.from_dict(config)
    done, _ = run_progress(config)
    report_start(queue, (label(config), done, os.uname().nodename))
    Path(log).parent.mkdir(parents=True, exist_ok=True)
    sys.stdout.flush()
    sys.stderr.flush()
    fd = os.open(log, os.O_WRONLY | os.O_CREAT | os.O_APPEND, 0o644)
    # The worker serves this trial only (max_calls=1): its output, and its env child's, stay in the log.
    os.dup2(fd, 1)
    os.dup2(fd, 2)
    print(f"[sweep] {time.strftime('%Y-%m-%d %H:%M:%S')} {label(config)}, from step {done}", flush=True)
    print(f"policy config: {json.dumps(config.to_dict())}", flush=True)
    from drem_maniskill.rl.train_policy import train_policy

    try:
        result = train_policy(config)
    except BaseException:
        traceback.print_exc()
        raise
    finally:
        sys.stdout.flush()
        sys.stderr.flush()
    return dict(steps=result["steps"], resumed_from=result["resumed_from"], last_eval=result["last_eval"])


def log_path(out, config: RLConfig) -> Path:
    """The trial's log file: ``<out>/logs/<preset>-<task>-<reward>-seed<S>.log``, or, for a run folder under ``out``
    that other trials of the same label share ``out`` with (one per reward checkpoint), the preset and that folder's
    path, ``<preset>-<task>-<variant>-seed<S>.log``."""
    try:
        parts = config.run_dir.resolve().relative_to(Path(out).resolve()).parts
    except ValueError:
        parts = ()
    if parts and parts[-3:] != (config.task, config.reward, f"seed{config.seed}"):
        name = "-".join((config.preset,) + tuple(p for p in parts if p != config.preset))
    else:
        name = label(config).replace(" ", "-")
    return Path(out) / "logs" / (name + ".log")


def _start_ray(ray, address: Optional[str]) -> None:
    """This machine's cores as a local Ray instance, or the running cluster at ``address``."""
    if address:
        ray.init(address=address, log_to_driver=False, runtime_env={"env_vars": TRIAL_ENV})
    else:
        # A local instance's workers inherit this environment: no runtime env (an agent ray[default] brings).
        for key, value in TRIAL_ENV.items():
            os.environ.setdefault(key, value)
        ray.init(num_cpus=os.cpu_count(), include_dashboard=False, log_to_driver=False)


def _error_text(err: BaseException) -> str:
    """The original error of a failed Ray task, on one line."""
    cause = getattr(err, "cause", None) or err
    text = " ".join(str(cause).split())
    return f"{type(cause).__name__}: {text[-300:]}"


def _print_starts(queue, started: set, total: int) -> None:
    """A progress line for each trial that began since the last call."""
    while queue is not None and not queue.empty():
        name, done, node = queue.get_nowait()
        started.add(name)
        where = f"from step {done}" if done else "new"
        print(f"[sweep] start {name} ({where}, on {node}) [{len(started)}/{total}]", flush=True)


def run_sweep(configs: Sequence[RLConfig], out, address: Optional[str] = None, cpus_per_trial: float = 1,
              gpus_per_trial: float = 0, max_retries: int = 2) -> dict:
    """Run every unfinished trial on Ray; a progress line per trial, a summary at the end; returns the trials."""
    if cpus_per_trial <= 0 or gpus_per_trial < 0:
        raise ValueError(f"--cpus-per-trial must be > 0 and --gpus-per-trial >= 0, got {cpus_per_trial}, "
                         f"{gpus_per_trial}")
    if not address and cpus_per_trial > (os.cpu_count() or 1):
        raise ValueError(f"--cpus-per-trial {cpus_per_trial} is more than this machine's {os.cpu_count()} cores")
    todo, trials = split_finished(configs)
    for trial in trials:
        print(f"[sweep] skip {trial['trial']}: finished, {_success(trial['last_eval'])}", flush=True)
    if todo:
        trials += _run_on_ray(todo, out, address, cpus_per_trial, gpus_per_trial, max_retries)
    return summarize(trials)


def _run_on_ray(todo: Sequence[RLConfig], out, address, cpus: float, gpus: float, max_retries: int) -> list:
    """Submit every trial as a Ray task and report each as it starts and ends."""
    ray = import_ray()
    _start_ray(ray, address)
    try:
        from ray.util.queue import Queue

        queue = Queue(actor_options={"num_cpus": 0})
        task = ray.remote(num_cpus=cpus, num_gpus=gpus, max_retries=max_retries, retry_exceptions=RETRY_EXCEPTIONS,
                          max_calls=1)(run_trial)
        print(f"[sweep] {len(todo)} trials on Ray ({ray.cluster_resources().get('CPU', 0):g} CPUs, "
              f"{cpus:g} per trial); logs in {Path(out) / 'logs'}", flush=True)
        pending = {task.remote(c.to_dict(), str(log_path(out, c)), os.getcwd(), queue): (c, time.time()) for c in todo}
        started, results = set(), []
        while pending:
            ready, _ = ray.wait(list(pending), num_returns=1, timeout=2.0)
            _print_starts(queue, started, len(todo))
            for ref in ready:
                config, t0 = pending.pop(ref)
                results.append(_finish(ray, ref, config, out, time.time() - t0, len(results) + 1, len(todo)))
        return results
    finally:
        ray.shutdown()


def _finish(ray, ref, config: RLConfig, out, seconds: float, n: int, total: int) -> dict:
    """The result of one trial's task, with its progress line."""
    trial = dict(trial=label(config), run_dir=str(config.run_dir))
    try:
        result = ray.get(ref)
    except Exception as err:  # the run's own error, or its worker lost after every retry
        trial.update(status="failed", error=_error_text(err), last_eval=run_progress(config)[1])
        print(f"[sweep] FAILED {trial['trial']}: {trial['error']} (log: {log_path(out, config)}) [{n}/{total}]",
              flush=True)
        return trial
    trial.update(status="done", last_eval=result["last_eval"], resumed_from=result["resumed_from"])
    print(f"[sweep] done {trial['trial']}: {_success(result['last_eval'])}, {seconds:.0f} s [{n}/{total}]",
          flush=True)
    return trial


def summarize(trials: list) -> dict:
    """Print one line per trial and the counts; returns ``{"trials", "failed"}``."""
    print(f"[sweep] summary: {len(trials)} trials", flush=True)
    for trial in sorted(trials, key=lambda t: t["run_dir"]):
        extra = trial.get("error") or _success(trial.get("last_eval"))
        print(f"  {trial['status']:<7} {trial['trial']}: {extra}  ({trial['run_dir']})", flush=True)
    counts = {s: sum(t["status"] == s for t in trials) for s in ("done", "skipped", "failed")}
    print("[sweep] " + ", ".join(f"{n} {s}" for s, n in counts.items()), flush=True)
    return dict(trials=trials, failed=counts["failed"])
