"""``train-policy``: an algorithm of ``rl.algos.ALGOS`` (SAC) with a reward of ``rl.rewards.REWARDS``.

Evaluation, checkpoints, resume.

The run loop names no reward and no algorithm: both come from their tables by the config's
``reward`` and ``algo``. Run dir (``RLConfig.run_dir``)::

    config.json              the RLConfig of the run
    reward_checkpoint.json   a DREM reward's checkpoint: {"path", "sha256"}; a resume must read the same file
    eval.csv                 steps, success_rate, mean_return, wall_time, train_success_rate (one row per evaluation)
    tb/                      TensorBoard (SB3's logger: train/*, rollout/*, eval/*, <reward>/* of a learned reward)
    sb3/from<N>/progress.csv SB3's csv log of the segment that started at step N
    checkpoints/latest.json  {"step": N, "dir": "step_N"}, replaced atomically after a checkpoint is complete
    checkpoints/step_N/      model.zip, replay_buffer.pkl, <reward>.pt (a learned reward: vice.pt), progress.json
    .lock                    held while a process trains the run (its pid inside); a second one waits, then fails
"""

from __future__ import annotations

import csv
import hashlib
import json
import os
import shutil
import time
from pathlib import Path
from typing import Optional, Sequence

import numpy as np
import torch
from stable_baselines3.common.callbacks import BaseCallback, CallbackList
from stable_baselines3.common.logger import Logger, make_output_format

from drem_maniskill.envs import check_env_id
from drem_maniskill.experts import rollout
from drem_maniskill.rl.algos import algo_spec
from drem_maniskill.rl.config import RLConfig
from drem_maniskill.rl.rewards import reward_checkpoint, reward_spec
from drem_maniskill.rl.run_env import make_eval_env, make_vec_env
from drem_maniskill.rl.run_policy import deterministic_policy, latest_checkpoint
from drem_maniskill.rl.vec_env import SubprocDictVecEnv
from drem_maniskill.utils.atomic import atomic_path, write_json
from drem_maniskill.utils.episodes import max_episode_steps
from drem_maniskill.utils.lock import folder_lock
from drem_maniskill.utils.progress import progress_bar

EVAL_COLUMNS = ("steps", "success_rate", "mean_return", "wall_time", "train_success_rate")
# Fields a resumed run may change; anything else must match the saved config.
RESUMABLE_FIELDS = ("steps", "out", "eval_every", "threads", "device")


# ---------------------------------------------------------------------------- evaluation
def evaluate_policy(model, env, seeds: Sequence[int], horizon: int) -> dict:
    """Deterministic policy on each seed for ``horizon`` steps: success rate (success at any step) and mean return."""
    act = deterministic_policy(model)
    episodes = [rollout(env, act, int(seed), horizon, stop_on_success=False) for seed in seeds]
    return dict(success_rate=float(np.mean([ep.success for ep in episodes])),
                mean_return=float(np.mean([ep.ret for ep in episodes])))


def training_success_rate(model) -> float:
    """SB3's success rate over its last finished training episodes (``rollout/success_rate``); 0 before one ends."""
    done = getattr(model, "ep_success_buffer", None)
    return float(np.mean(done)) if done else 0.0


def read_eval_csv(path) -> list[dict]:
    """Rows of an ``eval.csv`` as dicts of floats (``steps`` as int); a column an older file lacks, or left blank, is
    absent from its rows."""
    path = Path(path)
    if not path.exists():
        return []
    with path.open() as f:
        rows = [{k: float(v) for k, v in row.items() if v not in ("", None)} for row in csv.DictReader(f)]
    for row in rows:
        row["steps"] = int(row["steps"])
    return rows


def _write_eval_csv(path: Path, rows: list[dict]) -> None:
    with atomic_path(path) as tmp, tmp.open("w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=EVAL_COLUMNS)
        w.writeheader()
        for row in rows:
            w.writerow({k: row.get(k, "") for k in EVAL_COLUMNS})


# ---------------------------------------------------------------------------- checkpoints
def save_run_checkpoint(run_dir: Path, config: RLConfig, model, learned, progress: dict) -> Path:
    """Write the model (and replay buffer), a learned reward's state and progress to a new folder.

    Then point ``latest.json`` at it.
    """
    root = run_dir / "checkpoints"
    name = f"step_{model.num_timesteps}"
    final = root / name
    with atomic_path(final, directory=True) as tmp:
        algo_spec(config.algo).save(model, tmp)
        if learned is not None:
            torch.save(learned.state_dict(), tmp / f"{config.reward}.pt")
        (tmp / "progress.json").write_text(json.dumps(progress, indent=2) + "\n")
    # Only now is the checkpoint complete: an interruption before this line leaves the old one in charge.
    write_json(root / "latest.json", {"step": model.num_timesteps, "dir": name})
    # Older checkpoints, and the temp folders of interrupted ones.
    for old in root.iterdir():
        if old.is_dir() and old.name != name:
            shutil.rmtree(old, ignore_errors=True)
    return final


# ---------------------------------------------------------------------------- the callback
class RunCallback(BaseCallback):
    """Progress bar, a learned reward's updates, and every ``eval_every`` steps: evaluate, log, checkpoint."""

    def __init__(self, config: RLConfig, run_dir: Path, eval_env, learned, rows: list, wall_offset: float, total: int):
        super().__init__()
        self.config, self.run_dir, self.eval_env, self.learned = config, run_dir, eval_env, learned
        self.rows, self.wall_offset, self.total = rows, wall_offset, total
        self.horizon = max_episode_steps(config.task)
        self.seeds = [config.eval_seed + i for i in range(config.eval_episodes)]
        self.bar = None

    def _wall(self) -> float:
        return self.wall_offset + time.time() - self.t0

    def _on_training_start(self) -> None:
        self.t0 = time.time()
        self.bar = progress_bar(total=self.total, initial=self.num_timesteps, unit="step",
                                desc=f"{self.config.algo.upper()} {self.config.task} {self.config.reward} "
                                     f"seed{self.config.seed}")
        self.last_update = self.num_timesteps
        if not self.rows:
            self._evaluate()  # step 0: where every curve starts

    def _on_step(self) -> bool:
        self.bar.update(self.training_env.num_envs)
        return True

    def _on_rollout_end(self) -> None:
        # After the rollout's transitions are in the replay buffer: a checkpoint here misses none.
        if self.learned is not None and self.num_timesteps - self.last_update >= self.learned.update_every:
            self.last_update = self.num_timesteps
            for k, v in self.learned.update().items():
                self.logger.record(f"{self.config.reward}/{k}", v)
            relabel = getattr(self.learned, "relabel", None)
            if relabel is not None:  # a reward that changed pays the buffer's transitions again
                self.logger.record(f"{self.config.reward}/relabelled", relabel(self.model.replay_buffer))
        last = self.rows[-1]["steps"] if self.rows else -1
        due = self.num_timesteps // self.config.eval_every > max(last, 0) // self.config.eval_every
        if due or self.num_timesteps >= self.total:
            self._evaluate()
            self._checkpoint()

    def _evaluate(self) -> None:
        result = evaluate_policy(self.model, self.eval_env, self.seeds, self.horizon)
        # Whether training episodes ever succeed tells a reward that pulls the policy to the goal from one that
        # leaves it short, before the deterministic evaluation shows any success.
        row = dict(steps=self.num_timesteps, **result, wall_time=round(self._wall(), 2),
                   train_success_rate=round(training_success_rate(self.model), 4))
        self.rows.append(row)
        _write_eval_csv(self.run_dir / "eval.csv", self.rows)
        for k in ("success_rate", "mean_return"):
            self.logger.record(f"eval/{k}", result[k])
        self.logger.record("time/wall_time", row["wall_time"])
        self.logger.dump(self.num_timesteps)
        self.bar.set_postfix(success=f"{result['success_rate']:.2f}", ret=f"{result['mean_return']:.2f}")

    def _checkpoint(self) -> None:
        save_run_checkpoint(self.run_dir, self.config, self.model, self.learned,
                        dict(num_timesteps=self.num_timesteps, wall_time=self._wall(), eval_rows=len(self.rows)))

    def _on_training_end(self) -> None:
        if self.bar is not None:
            self.bar.close()


# ---------------------------------------------------------------------------- training
def resume_seed(seed: int, steps: int) -> int:
    """The env seed of a run resumed at ``steps``: new for every resume point, within numpy's 0..2**32 - 1."""
    return (int(seed) + 1_000_003 * int(steps)) % 2**32


def _comparable(config: RLConfig) -> dict:
    """``config.to_dict()`` with the DREM form as the run pays it (None for a reward that reads no DREM checkpoint)."""
    d = config.to_dict()
    d["drem_form"] = config.drem_form_used if reward_spec(config.reward).checkpoint else None
    return d


def check_resumable(config: RLConfig) -> None:
    """A ValueError when ``config.run_dir`` holds a checkpointed run whose config differs beyond resumable fields."""
    saved = config.run_dir / "config.json"
    if saved.exists() and latest_checkpoint(config.run_dir) is not None:
        _check_resumable(RLConfig.load(saved), config)


def _check_resumable(saved: RLConfig, config: RLConfig) -> None:
    now = _comparable(config)
    diff = {k: (v, now[k]) for k, v in _comparable(saved).items() if k not in RESUMABLE_FIELDS and v != now[k]}
    if diff:
        lines = ", ".join(f"{k}: saved {a!r}, now {b!r}" for k, (a, b) in diff.items())
        raise ValueError(f"{config.run_dir} holds a run with another config ({lines}); "
                         "use another --out or the same options")


def shown_path(path) -> str:
    """``path`` relative to the working directory when inside it (no home dirs in the repo's results), else as given."""
    shown = os.path.relpath(path)
    return str(path) if shown.startswith("..") else shown


def file_sha256(path) -> str:
    """Hex sha256 of a file's bytes."""
    digest = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def pin_reward_checkpoint(config: RLConfig, run_dir: Path, resuming: bool) -> Optional[dict]:
    """Record the DREM checkpoint that pays the run (path, sha256); a resumed run must be paid by the same file.

    The shipped checkpoints are retrained from time to time under the same path, so a config that
    says ``reward_checkpoint: null`` does not say which reward a run saw, and a resume after a
    retraining would switch rewards in the middle of a run without this check.
    """
    path = reward_checkpoint(config.reward, check_env_id(config.task), config.reward_checkpoint)
    if path is None or not path.exists():
        return None  # no DREM reward, or make_env names the missing file
    now = dict(path=shown_path(path), sha256=file_sha256(path))
    pin = run_dir / "reward_checkpoint.json"
    if resuming and pin.exists():
        saved = json.loads(pin.read_text())
        if saved["sha256"] != now["sha256"]:
            raise ValueError(
                f"{run_dir} was trained on the reward checkpoint {saved['path']} (sha256 {saved['sha256'][:12]}), "
                f"and {path} is now another file (sha256 {now['sha256'][:12]}): resume with --reward-checkpoint "
                "pointing at a copy of the original, or start a new run with another --out")
        return saved
    write_json(pin, now)
    return now


def train_policy(config: RLConfig, callbacks: Sequence[BaseCallback] = ()) -> dict:
    """Train (or resume) as ``config`` says; returns the run dir, steps, resumed-from step and last evaluation."""
    reward_spec(config.reward)  # unknown names fail before anything is built
    algo = algo_spec(config.algo)
    torch.set_num_threads(int(config.threads))
    config.run_dir.mkdir(parents=True, exist_ok=True)
    with run_lock(config.run_dir):
        return _train_locked(config, algo, callbacks)


# A killed sweep's Ray workers can outlive it by seconds; a rerun waits this long for them before it fails.
LOCK_WAIT_S = 120.0


def run_lock(run_dir, wait_s: Optional[float] = None):
    """Hold ``run_dir/.lock`` for one training process; another waits up to ``wait_s`` (LOCK_WAIT_S), then fails."""
    return folder_lock(run_dir, LOCK_WAIT_S if wait_s is None else wait_s, "trained",
                       "this run resumes from its last checkpoint", "train-policy")


def _train_locked(config: RLConfig, algo, callbacks: Sequence[BaseCallback]) -> dict:
    """``train_policy``'s body, run while the run folder's lock is held."""
    run_dir = config.run_dir
    ckpt = latest_checkpoint(run_dir)
    check_resumable(config)
    config.save(run_dir / "config.json")
    pinned = pin_reward_checkpoint(config, run_dir, resuming=ckpt is not None)

    fresh = dict(num_timesteps=0, wall_time=0.0, eval_rows=0)
    progress = json.loads((ckpt / "progress.json").read_text()) if ckpt else fresh
    rows = read_eval_csv(run_dir / "eval.csv")
    # Rows written after the checkpoint (an interruption between the two) belong to a future that is re-run.
    rows = [r for r in rows if r["steps"] <= progress["num_timesteps"]] if ckpt else []

    learned_file = ckpt / f"{config.reward}.pt" if ckpt else None
    learned_state = torch.load(learned_file, weights_only=True) if learned_file and learned_file.exists() else None
    venv, learned = make_vec_env(config, learned_state=learned_state)
    try:
        eval_env = make_eval_env(config, learned)
    except BaseException:
        venv.close()
        raise
    try:
        if ckpt is not None:
            model = algo.load(ckpt, venv, config.device)
            model._last_obs = None  # the env was rebuilt: start a fresh episode rather than trust a stale obs
            # A new seed for the resumed env's episodes (the same one would replay the first episodes).
            venv.seed(resume_seed(config.seed, model.num_timesteps))
        else:
            model = algo.build(config, venv)
        if isinstance(venv, SubprocDictVecEnv):
            model.train_while_env_steps(venv)
        start = model.num_timesteps
        model.set_logger(Logger(None, [make_output_format("csv", str(run_dir / "sb3" / f"from{start}")),
                                       make_output_format("tensorboard", str(run_dir / "tb"))]))
        run = RunCallback(config, run_dir, eval_env, learned, rows, progress["wall_time"], config.steps)
        if start < config.steps:
            model.learn(total_timesteps=config.steps - start, reset_num_timesteps=False,
                        callback=CallbackList([run, *callbacks]), log_interval=4)
        return dict(run_dir=str(run_dir), steps=model.num_timesteps, resumed_from=start,
                    last_eval=rows[-1] if rows else None, env_time=venv.env_time, reward_checkpoint=pinned)
    finally:
        venv.close()
        eval_env.close()
