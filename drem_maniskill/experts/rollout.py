"""The one rollout loop, and what is built on it: success rates and VICE-RAQ's goal examples.

``rollout(env, policy, seed)`` runs one episode and returns an ``Episode``. Recording expert
demos (``experts.recording``), the reward examination (``evaluate.examine``), the SAC
evaluation (``rl.train_policy``) and the tests all run their episodes through it; what they
measure along the way goes in through ``measure``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Callable, Iterable, Optional, Sequence

import gymnasium as gym
import numpy as np
import torch

from drem_maniskill.experts.control import ee_control_kwargs
from drem_maniskill.experts.policies import get_policy
from drem_maniskill.utils.cameras import camera_images
from drem_maniskill.utils.episodes import episode_horizon
from drem_maniskill.utils.progress import progress_bar


@dataclass
class Episode:
    """One episode of the first env of a batch: rewards per step, success, length, the last obs and info."""

    seed: Optional[int]
    rewards: list = field(default_factory=list)
    success: bool = False  # success at any step
    length: int = 0
    measures: dict = field(default_factory=dict)  # name -> one value per step, from ``measure``
    obs: Any = None
    info: dict = field(default_factory=dict)

    @property
    def ret(self) -> float:
        """Sum of the rewards."""
        return float(sum(self.rewards))


def rollout(env, policy: Callable, seed: Optional[int], steps: Optional[int] = None, stop_on_success: bool = True,
            measure: Optional[Callable] = None) -> Episode:
    """One episode of ``policy`` from ``env.reset(seed=seed)``.

    It runs ``steps`` steps (default: the env's episode length) and ends early at truncation
    and, with ``stop_on_success``, at the first success or termination (ManiSkill terminates on
    success). ``measure(env, obs, action, info)`` may return a dict of floats per step, kept in
    ``Episode.measures``.
    """
    obs, info = env.reset(seed=seed)
    ep = Episode(seed=seed)
    for _ in range(steps or episode_horizon(env)):
        action = policy(obs)
        obs, reward, terminated, truncated, info = env.step(action)
        ep.length += 1
        ep.rewards.append(float(torch.as_tensor(reward).reshape(-1)[0]))
        success = bool(info["success"].reshape(-1)[0])
        ep.success = ep.success or success
        if measure is not None:
            for key, value in measure(env, obs, action, info).items():
                ep.measures.setdefault(key, []).append(value)
        if (stop_on_success and (success or bool(terminated.any()))) or bool(truncated.any()):
            break
    ep.obs, ep.info = obs, info
    return ep


def success_rate(env_id: str, name: str = "expert", seeds=range(100), env_kwargs=None) -> dict:
    """Run a scripted policy once per seed; return the success rate and per-seed outcomes."""
    env = gym.make(env_id, obs_mode="state_dict", **ee_control_kwargs(env_id, env_kwargs))
    policy = get_policy(name, env)
    horizon = episode_horizon(env)
    try:
        episodes = [rollout(env, policy, int(seed), horizon)
                    for seed in progress_bar(list(seeds), desc=f"{name} on {env_id}", unit="episode")]
    finally:
        env.close()
    outcomes = [ep.success for ep in episodes]
    lengths = [ep.length for ep in episodes]
    solved = [n for n, ok in zip(lengths, outcomes) if ok]
    return dict(env_id=env_id, policy=name, episodes=len(outcomes), horizon=horizon,
                success_rate=sum(outcomes) / max(len(outcomes), 1), mean_length=float(np.mean(lengths)),
                mean_success_length=float(np.mean(solved)) if solved else float("nan"),
                failed_seeds=[int(s) for s, ok in zip(seeds, outcomes) if not ok])


def collect_goal_examples(
    env_id: str,
    seeds: Iterable[int],
    env_kwargs: Optional[dict] = None,
    cameras: Sequence[str] = ("fixed_camera", "wrist_camera"),
    max_steps: int = 50,
    env: Optional[gym.Env] = None,
) -> dict:
    """Roll out the scripted expert on each seed; the first successful observation's images per seed.

    Returns ``{uid: uint8 [N, H, W, 3]}`` with ``N <= len(seeds)`` (seeds where the expert
    fails are skipped): VICE-RAQ's goal examples. Pass ``env`` to reuse an env (made with
    ``obs_mode="rgb"``; it is reset); otherwise one is made from ``env_id`` and ``env_kwargs``
    and closed. Use the RL env's own kwargs (render style, colours, camera sizes) so the goals
    look like its states.
    """
    own = env is None
    if own:
        env = gym.make(env_id, **{**dict(env_kwargs or {}), "obs_mode": "rgb"})
    try:
        if env.unwrapped.num_envs != 1:
            raise ValueError("collect_goal_examples rolls out one seed at a time; use an env with num_envs=1")
        found = {uid: [] for uid in cameras}
        for seed in seeds:
            ep = rollout(env, get_policy("expert", env, seed=int(seed)), int(seed), max_steps)
            if ep.success:
                for uid, image in camera_images(env, ep.obs, cameras).items():
                    found[uid].append(torch.as_tensor(image[0]).cpu())
    finally:
        if own:
            env.close()
    if not found[cameras[0]]:
        raise RuntimeError(f"the expert succeeded on none of the seeds on {env_id}; no goal examples")
    return {uid: torch.stack(v) for uid, v in found.items()}
