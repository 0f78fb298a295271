"""SAC (stable-baselines3) on our tasks with any of the compared rewards (the paper's Fig. 5).

``train_policy(PolicyConfig(task=..., reward=..., seed=..., steps=...))`` trains SAC and writes a
run folder ``outputs/rl/<task>/<reward>/seed<S>/``:

* ``config.json``: the config;
* ``eval.csv``: ``steps, success_rate, mean_return, wall_time`` every ``eval_every`` steps, on
  the fixed held-out seeds ``eval_seed_start ...`` (deterministic policy);
* ``progress.csv`` and ``tb/``: SB3's training log (CSV and TensorBoard);
* ``checkpoint/``: model, replay buffer, VICE state and step count, written atomically at
  every evaluation; running the same command again resumes from it.

Rewards (``REWARDS``): ``sparse`` (success), ``dense`` (the task's ``normalized_dense``),
``engineered`` (``-exp(kappa * ||x - x_G||)``), ``vice`` (VICE-RAQ), ``drem-image`` (DREM
without F/T: ``rewards/<task>/drem_image.pt``) and ``drem``. The policy's observation is the
same for every reward within a preset, so the comparison changes only the reward:

* ``light`` (this CPU machine): proprioception (joint positions, TCP pose), the 8 x 6 F/T
  history and both cameras downscaled to 32 x 32, through a small CNN per camera; batches of 64;
* ``paper``: both cameras at 64 x 64 (the paper's policy input is images), plus the F/T
  history for ``drem`` only (the paper gives DREM's policy F/T and the baselines not).
"""

from __future__ import annotations

import csv
import json
import os
import shutil
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Optional

import cv2
import gymnasium as gym
import numpy as np
import torch
from stable_baselines3.common.torch_layers import BaseFeaturesExtractor
from torch import nn

# name -> env kwargs (reward_mode) and extras. One line adds a reward.
REWARDS = {
    "sparse": dict(reward_mode="sparse"),
    "dense": dict(reward_mode="normalized_dense"),
    "engineered": dict(reward_mode="engineered"),
    "vice": dict(reward_mode="sparse", vice=True),  # the env's reward is replaced by the classifier's
    "drem-image": dict(reward_mode="drem", image_only=True),
    "drem": dict(reward_mode="drem"),
}

PRESETS = {
    # Batch 64: on this CPU SAC's gradient step with 256 samples (two cameras) takes ~0.3 s.
    "light": dict(image_size=32, proprio=True, ft="all", batch_size=64, learning_starts=250),
    "paper": dict(image_size=64, proprio=False, ft="drem"),
    "tiny": dict(image_size=32, proprio=True, ft="all", learning_starts=32, batch_size=32, eval_episodes=2,
                 eval_every=64, vice_update_every=32),
}


@dataclass
class PolicyConfig:
    """SAC run settings; ``preset`` fills the observation and scale fields."""

    task: str = "PegInHole-v1"
    reward: str = "drem"
    seed: int = 0
    steps: int = 10_000
    preset: str = "light"
    image_size: int = 32
    proprio: bool = True
    ft: str = "all"  # "all", "drem" (only when the reward is drem) or "none"
    eval_every: int = 1_000
    eval_episodes: int = 10
    eval_seed_start: int = 10_000
    learning_starts: int = 500
    batch_size: int = 256
    learning_rate: float = 3e-4
    gamma: float = 0.9  # 50-step episodes at 5 Hz
    vice_update_every: int = 1_000
    vice_queries: Optional[int] = None
    threads: Optional[int] = None
    out: str = ""

    @classmethod
    def preset_config(cls, preset: str, **overrides) -> "PolicyConfig":
        """The config of a preset (``light``, ``paper``, ``tiny``) with ``overrides``."""
        if preset not in PRESETS:
            raise ValueError(f"unknown policy preset {preset!r}; choose one of {list(PRESETS)}")
        config = cls(**{**PRESETS[preset], "preset": preset, **{k: v for k, v in overrides.items() if v is not None}})
        if config.reward not in REWARDS:
            raise ValueError(f"unknown reward {config.reward!r}; choose one of {list(REWARDS)}")
        if not config.out:
            config.out = f"outputs/rl/{config.task}/{config.reward}/seed{config.seed}"
        return config

    @property
    def uses_ft(self) -> bool:
        """Whether the policy sees the F/T history."""
        return self.ft == "all" or (self.ft == "drem" and self.reward == "drem")


# ---------------------------------------------------------------------------- env
class PolicyObservation(gym.ObservationWrapper):
    """ManiSkill's numpy observation (after ``CPUGymWrapper``) -> the policy's compact dict."""

    CAMERAS = ("fixed_camera", "wrist_camera")

    def __init__(self, env: gym.Env, config: PolicyConfig):
        super().__init__(env)
        self.config = config
        s = config.image_size
        spaces = {c: gym.spaces.Box(0, 255, (3, s, s), np.uint8) for c in self.CAMERAS}
        width = (7 + 7 if config.proprio else 0) + (48 if config.uses_ft else 0)
        if width:
            spaces["state"] = gym.spaces.Box(-np.inf, np.inf, (width,), np.float32)
        self.observation_space = gym.spaces.Dict(spaces)

    def observation(self, obs):
        """Downscale the cameras (area) and stack proprioception and F/T."""
        s = self.config.image_size
        out = {}
        for c in self.CAMERAS:
            img = np.asarray(obs["sensor_data"][c]["rgb"])
            if img.shape[0] != s:
                img = cv2.resize(img, (s, s), interpolation=cv2.INTER_AREA)
            out[c] = np.ascontiguousarray(img.transpose(2, 0, 1))
        parts = []
        if self.config.proprio:
            parts += [np.asarray(obs["agent"]["qpos"])[:7], np.asarray(obs["extra"]["tcp_pose"])]
        if self.config.uses_ft:
            # Newtons: tens in contact; scaled to order one for the networks.
            parts.append(np.asarray(obs["extra"]["ft"]).reshape(-1) / 10.0)
        if parts:
            out["state"] = np.concatenate(parts).astype(np.float32)
        return out


def make_env(config: PolicyConfig, vice_goals=None):
    """The training env: ManiSkill task with the chosen reward, numpy, the policy's observation."""
    from mani_skill.utils.wrappers.gymnasium import CPUGymWrapper

    import drem_maniskill  # noqa: F401
    from drem_maniskill.drem.reward import resolve_checkpoint

    spec = REWARDS[config.reward]
    kwargs = dict(obs_mode="rgb", reward_mode=spec["reward_mode"])
    if spec.get("image_only"):
        kwargs["drem_checkpoint"] = str(resolve_checkpoint(config.task, None, image_only=True))
    env = gym.make(config.task, **kwargs)
    vice = None
    if spec.get("vice"):
        from drem_maniskill.baselines.vice import VICEConfig, VICERewardWrapper, collect_goal_examples

        goals = vice_goals if vice_goals is not None else collect_goal_examples(config.task, seeds=range(20_000, 20_010))
        env = vice = VICERewardWrapper(env, goals, VICEConfig(update_every=config.vice_update_every,
                                                              max_queries=config.vice_queries, seed=config.seed))
    # SB3's Monitor, not CPUGymWrapper's metrics: SB3 reads its own episode keys from info.
    from stable_baselines3.common.monitor import Monitor

    env = Monitor(PolicyObservation(CPUGymWrapper(env, ignore_terminations=False), config))
    return env, vice


# ---------------------------------------------------------------------------- policy net
class SmallCNNExtractor(BaseFeaturesExtractor):
    """Per camera a 3-layer stride-2 CNN to 64 features; the state vector passes through."""

    def __init__(self, observation_space: gym.spaces.Dict):
        cams = [k for k in observation_space.spaces if k != "state"]
        state_dim = observation_space["state"].shape[0] if "state" in observation_space.spaces else 0
        super().__init__(observation_space, 64 * len(cams) + state_dim)
        self.cams, self.state_dim = cams, state_dim
        self.cnns = nn.ModuleDict()
        for k in cams:
            c, h, w = observation_space[k].shape
            cnn = nn.Sequential(
                nn.Conv2d(c, 16, 3, 2, 1), nn.ReLU(), nn.Conv2d(16, 32, 3, 2, 1), nn.ReLU(),
                nn.Conv2d(32, 32, 3, 2, 1), nn.ReLU(), nn.Flatten(),
            )
            with torch.no_grad():
                n = cnn(torch.zeros(1, c, h, w)).shape[1]
            self.cnns[k] = nn.Sequential(cnn, nn.Linear(n, 64), nn.ReLU())

    def forward(self, obs: dict) -> torch.Tensor:
        """Features ``[B, features_dim]``; SB3 has already scaled images to [0, 1]."""
        parts = [self.cnns[k](obs[k]) for k in self.cams]
        if self.state_dim:
            parts.append(obs["state"])
        return torch.cat(parts, dim=1)


# ---------------------------------------------------------------------------- evaluation
def evaluate_policy(model, config: PolicyConfig, env=None) -> dict:
    """Success rate and mean return of the deterministic policy on the held-out seeds."""
    successes, returns = [], []
    for k in range(config.eval_episodes):
        obs, _ = env.reset(seed=config.eval_seed_start + k)
        done, ret, success = False, 0.0, False
        while not done:
            action, _ = model.predict(obs, deterministic=True)
            obs, reward, terminated, truncated, info = env.step(action)
            ret += float(reward)
            success = success or bool(info.get("success", False))
            done = bool(terminated or truncated)
        successes.append(success)
        returns.append(ret)
    return dict(success_rate=float(np.mean(successes)), mean_return=float(np.mean(returns)))


# ---------------------------------------------------------------------------- training
def _atomic_dir_replace(tmp: Path, final: Path) -> None:
    old = final.with_name(final.name + ".old")
    if final.exists():
        os.replace(final, old)
    os.replace(tmp, final)
    if old.exists():
        shutil.rmtree(old)


def _save_checkpoint(out: Path, model, vice, steps: int, wall_time: float) -> None:
    tmp = out / "checkpoint.tmp"
    if tmp.exists():
        shutil.rmtree(tmp)
    tmp.mkdir(parents=True)
    model.save(tmp / "model.zip")
    model.save_replay_buffer(tmp / "replay_buffer.pkl")
    if vice is not None:
        torch.save(vice.state_dict(), tmp / "vice.pt")
    (tmp / "progress.json").write_text(json.dumps({"steps": steps, "wall_time": wall_time}))
    _atomic_dir_replace(tmp, out / "checkpoint")


def train_policy(config: PolicyConfig, progress: bool = True, vice_goals=None) -> Path:
    """Train SAC as configured; resumes from ``<out>/checkpoint``. Returns the run folder."""
    from stable_baselines3 import SAC
    from stable_baselines3.common.callbacks import BaseCallback
    from stable_baselines3.common.logger import configure
    from tqdm import tqdm

    if config.reward not in REWARDS:
        raise ValueError(f"unknown reward {config.reward!r}; choose one of {list(REWARDS)}")
    if config.threads:
        torch.set_num_threads(config.threads)
    out = Path(config.out)
    out.mkdir(parents=True, exist_ok=True)
    saved = out / "config.json"
    if saved.exists() and (out / "checkpoint").exists():
        before = {k: v for k, v in json.loads(saved.read_text()).items() if k not in ("steps", "threads", "out")}
        now = {k: v for k, v in json.loads(json.dumps(asdict(config))).items() if k not in ("steps", "threads", "out")}
        if before != now:
            diff = sorted(k for k in now if before.get(k) != now[k])
            raise ValueError(f"{out} holds a run with other settings ({diff}); pass another --out or delete it")
    saved.write_text(json.dumps(asdict(config), indent=2))

    env, vice = make_env(config, vice_goals)
    # A separate env for evaluation, so SB3's episode in progress is not disturbed; for VICE it
    # has the sparse reward (the classifier lives in the training env), so its return is sparse.
    eval_config = PolicyConfig(**{**asdict(config), "reward": "sparse"}) if vice is not None else config
    eval_env, _ = make_env(eval_config)
    ckpt = out / "checkpoint"
    done_steps, wall_done = 0, 0.0
    if (ckpt / "model.zip").exists():
        model = SAC.load(ckpt / "model.zip", env=env, device="cpu")
        model.load_replay_buffer(ckpt / "replay_buffer.pkl")
        if vice is not None and (ckpt / "vice.pt").exists():
            vice.load_state_dict(torch.load(ckpt / "vice.pt", weights_only=False))
        saved_progress = json.loads((ckpt / "progress.json").read_text())
        done_steps, wall_done = int(saved_progress["steps"]), float(saved_progress.get("wall_time", 0.0))
    else:
        model = SAC(
            "MultiInputPolicy", env, learning_rate=config.learning_rate, buffer_size=max(config.steps, 1000),
            learning_starts=config.learning_starts, batch_size=config.batch_size, gamma=config.gamma, seed=config.seed,
            policy_kwargs=dict(features_extractor_class=SmallCNNExtractor, net_arch=[256, 256]), device="cpu",
            verbose=0,
        )
    model.set_logger(configure(str(out), ["csv", "tensorboard"]))
    eval_csv = out / "eval.csv"
    if done_steps == 0:
        with open(eval_csv, "w", newline="") as f:
            csv.writer(f).writerow(["steps", "success_rate", "mean_return", "wall_time"])
    elif eval_csv.exists():
        # Rows written after the checkpoint we resume from belong to lost work.
        rows = list(csv.reader(open(eval_csv)))
        with open(eval_csv, "w", newline="") as f:
            csv.writer(f).writerows([rows[0]] + [r for r in rows[1:] if int(r[0]) <= done_steps])
    wall0 = time.time() - wall_done  # wall time counts across resumes

    class Periodic(BaseCallback):
        def __init__(self):
            super().__init__()
            self.bar = tqdm(total=config.steps, initial=done_steps, desc=f"SAC {config.task} {config.reward} s{config.seed}",
                            unit="step", disable=not progress)

        def _on_step(self) -> bool:
            steps = self.model.num_timesteps
            self.bar.update(1)
            if vice is not None and steps % config.vice_update_every == 0:
                for key, value in vice.update().items():
                    self.logger.record(f"vice/{key}", value)
            if steps % config.eval_every == 0 or steps >= config.steps:
                result = evaluate_policy(self.model, config, eval_env)
                self.logger.record("eval/success_rate", result["success_rate"])
                self.logger.record("eval/mean_return", result["mean_return"])
                with open(eval_csv, "a", newline="") as f:
                    csv.writer(f).writerow([steps, result["success_rate"], result["mean_return"], round(time.time() - wall0, 1)])
                _save_checkpoint(out, self.model, vice, steps, time.time() - wall0)
                self.bar.set_postfix(success=f"{result['success_rate']:.0%}")
            return True

    remaining = config.steps - done_steps
    if remaining > 0:
        callback = Periodic()
        model.learn(total_timesteps=remaining, callback=callback, reset_num_timesteps=False, progress_bar=False)
        callback.bar.close()
    env.close()
    if eval_env is not env:
        eval_env.close()
    return out
