"""``train-policy``: SAC (stable-baselines3) on our tasks with a reward chosen by name; evaluation, checkpoints, resume.

Run dir (``RLConfig.run_dir``)::

    config.json              the RLConfig of the run
    eval.csv                 steps, success_rate, mean_return, wall_time (one row per evaluation)
    tb/                      TensorBoard (SB3's logger: train/*, rollout/*, eval/*, vice/*)
    sb3/from<N>/progress.csv SB3's csv log of the segment that started at step N
    checkpoints/latest.json  {"step": N, "dir": "step_N"}, replaced atomically after a checkpoint is complete
    checkpoints/step_N/      model.zip, replay_buffer.pkl, vice.pt (VICE only), progress.json
"""

from __future__ import annotations

import csv
import json
import os
import shutil
import time
from pathlib import Path
from typing import Optional, Sequence

import numpy as np
import torch
from stable_baselines3 import SAC
from stable_baselines3.common.callbacks import BaseCallback, CallbackList
from stable_baselines3.common.logger import Logger, make_output_format

from drem_maniskill.rl.config import RLConfig
from drem_maniskill.rl.envs import ManiSkillDictVecEnv, make_env, max_episode_steps, reward_spec
from drem_maniskill.rl.policy import MultimodalExtractor

EVAL_COLUMNS = ("steps", "success_rate", "mean_return", "wall_time")
# Fields a resumed run may change; anything else must match the saved config.
RESUMABLE_FIELDS = ("steps", "out", "eval_every", "threads", "device")


# ---------------------------------------------------------------------------- evaluation
def evaluate(model, env, seeds: Sequence[int], horizon: int) -> dict:
    """Deterministic policy on each seed for ``horizon`` steps: success rate (success at any step) and mean return."""
    successes, returns = [], []
    for seed in seeds:
        obs, _ = env.reset(seed=int(seed))
        ret, success = 0.0, False
        for _ in range(horizon):
            action, _ = model.predict({k: v.cpu().numpy() for k, v in obs.items()}, deterministic=True)
            obs, reward, _terminated, _truncated, info = env.step(torch.as_tensor(action, dtype=torch.float32))
            ret += float(reward.reshape(-1)[0])
            success |= bool(info["success"].reshape(-1)[0])
        successes.append(success)
        returns.append(ret)
    return dict(success_rate=float(np.mean(successes)), mean_return=float(np.mean(returns)))


def read_eval_csv(path) -> list[dict]:
    """Rows of an ``eval.csv`` as dicts of floats (``steps`` as int)."""
    path = Path(path)
    if not path.exists():
        return []
    with path.open() as f:
        rows = [{k: float(v) for k, v in row.items()} for row in csv.DictReader(f)]
    for row in rows:
        row["steps"] = int(row["steps"])
    return rows


def _write_eval_csv(path: Path, rows: list[dict]) -> None:
    tmp = path.with_suffix(".csv.tmp")
    with tmp.open("w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=EVAL_COLUMNS)
        w.writeheader()
        for row in rows:
            w.writerow({k: row[k] for k in EVAL_COLUMNS})
    os.replace(tmp, path)


# ---------------------------------------------------------------------------- checkpoints
def latest_checkpoint(run_dir) -> Optional[Path]:
    """The newest complete checkpoint folder of a run, or None."""
    latest = Path(run_dir) / "checkpoints" / "latest.json"
    if not latest.exists():
        return None
    folder = latest.parent / json.loads(latest.read_text())["dir"]
    return folder if folder.exists() else None


def _atomic_json(path: Path, data: dict) -> None:
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(json.dumps(data, indent=2) + "\n")
    os.replace(tmp, path)


def save_checkpoint(run_dir: Path, model, vice, progress: dict) -> Path:
    """Write model, replay buffer, VICE state and progress to a new folder, then point ``latest.json`` at it."""
    root = run_dir / "checkpoints"
    root.mkdir(parents=True, exist_ok=True)
    name = f"step_{model.num_timesteps}"
    tmp = root / (name + ".tmp")
    shutil.rmtree(tmp, ignore_errors=True)
    tmp.mkdir()
    model.save(tmp / "model.zip")
    model.save_replay_buffer(tmp / "replay_buffer.pkl")
    if vice is not None:
        torch.save(vice.state_dict(), tmp / "vice.pt")
    (tmp / "progress.json").write_text(json.dumps(progress, indent=2) + "\n")
    final = root / name
    shutil.rmtree(final, ignore_errors=True)
    os.replace(tmp, final)
    # Only now is the checkpoint complete: an interruption before this line leaves the old one in charge.
    _atomic_json(root / "latest.json", {"step": model.num_timesteps, "dir": name})
    for old in root.iterdir():
        if old.is_dir() and old.name != name:
            shutil.rmtree(old, ignore_errors=True)
    return final


# ---------------------------------------------------------------------------- the callback
class RunCallback(BaseCallback):
    """Progress bar, VICE classifier updates, and every ``eval_every`` steps: evaluate, log, checkpoint."""

    def __init__(self, config: RLConfig, run_dir: Path, eval_env, vice, rows: list, wall_offset: float, total: int):
        super().__init__()
        self.config, self.run_dir, self.eval_env, self.vice = config, run_dir, eval_env, vice
        self.rows, self.wall_offset, self.total = rows, wall_offset, total
        self.horizon = max_episode_steps(config.task)
        self.seeds = [config.eval_seed + i for i in range(config.eval_episodes)]
        self.bar = None

    def _wall(self) -> float:
        return self.wall_offset + time.time() - self.t0

    def _on_training_start(self) -> None:
        from tqdm.auto import tqdm

        self.t0 = time.time()
        self.bar = tqdm(total=self.total, initial=self.num_timesteps, unit="step",
                        desc=f"SAC {self.config.task} {self.config.reward} seed{self.config.seed}")
        self.last_vice = self.num_timesteps
        if not self.rows:
            self._evaluate()  # step 0: where every curve starts

    def _on_step(self) -> bool:
        self.bar.update(self.training_env.num_envs)
        return True

    def _on_rollout_end(self) -> None:
        # After the rollout's transitions are in the replay buffer: a checkpoint here misses none.
        if self.vice is not None and self.num_timesteps - self.last_vice >= self.vice.config.update_every:
            self.last_vice = self.num_timesteps
            for k, v in self.vice.update().items():
                self.logger.record(f"vice/{k}", v)
        last = self.rows[-1]["steps"] if self.rows else -1
        due = self.num_timesteps // self.config.eval_every > max(last, 0) // self.config.eval_every
        if due or self.num_timesteps >= self.total:
            self._evaluate()
            self._checkpoint()

    def _evaluate(self) -> None:
        result = evaluate(self.model, self.eval_env, self.seeds, self.horizon)
        row = dict(steps=self.num_timesteps, **result, wall_time=round(self._wall(), 2))
        self.rows.append(row)
        _write_eval_csv(self.run_dir / "eval.csv", self.rows)
        for k in ("success_rate", "mean_return"):
            self.logger.record(f"eval/{k}", result[k])
        self.logger.record("time/wall_time", row["wall_time"])
        self.logger.dump(self.num_timesteps)
        self.bar.set_postfix(success=f"{result['success_rate']:.2f}", ret=f"{result['mean_return']:.2f}")

    def _checkpoint(self) -> None:
        save_checkpoint(self.run_dir, self.model, self.vice,
                        dict(num_timesteps=self.num_timesteps, wall_time=self._wall(), eval_rows=len(self.rows)))

    def _on_training_end(self) -> None:
        if self.bar is not None:
            self.bar.close()


# ---------------------------------------------------------------------------- training
def _check_resumable(saved: RLConfig, config: RLConfig) -> None:
    diff = {k: (v, getattr(config, k)) for k, v in saved.to_dict().items()
            if k not in RESUMABLE_FIELDS and v != config.to_dict()[k]}
    if diff:
        lines = ", ".join(f"{k}: saved {a!r}, now {b!r}" for k, (a, b) in diff.items())
        raise ValueError(f"{config.run_dir} holds a run with another config ({lines}); use another --out or the same options")


def build_sac(config: RLConfig, venv) -> SAC:
    """A fresh SB3 SAC with ``MultiInputPolicy`` and our extractor, as ``config`` says."""
    return SAC(
        "MultiInputPolicy", venv, learning_rate=config.learning_rate,
        # No more transitions than steps: SB3 allocates (and pickles) the whole buffer.
        buffer_size=min(config.buffer_size, config.steps), batch_size=config.batch_size,
        learning_starts=config.learning_starts, train_freq=config.train_freq, gradient_steps=config.gradient_steps,
        gamma=config.gamma, tau=config.tau, ent_coef=config.ent_coef, seed=config.seed, device=config.device,
        policy_kwargs=dict(
            features_extractor_class=MultimodalExtractor,
            features_extractor_kwargs=dict(cnn_channels=config.cnn_channels, camera_features=config.camera_features,
                                           ft_features=config.ft_features),
            net_arch=list(config.net_arch), share_features_extractor=config.share_features_extractor,
        ),
    )


def train_policy(config: RLConfig, callbacks: Sequence[BaseCallback] = ()) -> dict:
    """Train (or resume) SAC as ``config`` says; returns the run dir, steps, resumed-from step and last evaluation."""
    spec = reward_spec(config.reward)  # unknown names fail before anything is built
    del spec
    torch.set_num_threads(int(config.threads))
    run_dir = config.run_dir
    run_dir.mkdir(parents=True, exist_ok=True)
    ckpt = latest_checkpoint(run_dir)
    if (run_dir / "config.json").exists() and ckpt is not None:
        _check_resumable(RLConfig.load(run_dir / "config.json"), config)
    config.save(run_dir / "config.json")

    progress = json.loads((ckpt / "progress.json").read_text()) if ckpt else dict(num_timesteps=0, wall_time=0.0, eval_rows=0)
    rows = read_eval_csv(run_dir / "eval.csv")
    # Rows written after the checkpoint (an interruption between the two) belong to a future that is re-run.
    rows = [r for r in rows if r["steps"] <= progress["num_timesteps"]] if ckpt else []

    vice_state = torch.load(ckpt / "vice.pt", weights_only=True) if ckpt and (ckpt / "vice.pt").exists() else None
    goals = vice_state["positives"][: vice_state["num_goal_examples"]] if vice_state else None
    env, vice = make_env(config, vice_goal_examples=goals)
    if vice_state is not None:
        vice.load_state_dict(vice_state)
    eval_env, _ = make_env(config, shared_vice=vice, for_eval=True)
    venv = ManiSkillDictVecEnv(env, max_episode_steps(config.task))
    try:
        if ckpt is not None:
            model = SAC.load(ckpt / "model.zip", env=venv, device=config.device)
            model.load_replay_buffer(ckpt / "replay_buffer.pkl")
            model._last_obs = None  # the env was rebuilt: start a fresh episode rather than trust a stale obs
            # A new seed for the resumed env's episodes (the same one would replay the first episodes).
            venv.seed(config.seed + 1_000_003 * model.num_timesteps)
        else:
            model = build_sac(config, venv)
        start = model.num_timesteps
        model.set_logger(Logger(None, [make_output_format("csv", str(run_dir / "sb3" / f"from{start}")),
                                       make_output_format("tensorboard", str(run_dir / "tb"))]))
        run = RunCallback(config, run_dir, eval_env, vice, rows, progress["wall_time"], config.steps)
        if start < config.steps:
            model.learn(total_timesteps=config.steps - start, reset_num_timesteps=False,
                        callback=CallbackList([run, *callbacks]), log_interval=4)
        return dict(run_dir=str(run_dir), steps=model.num_timesteps, resumed_from=start,
                    last_eval=rows[-1] if rows else None, env_time=venv.env_time)
    finally:
        venv.close()
        eval_env.close()
