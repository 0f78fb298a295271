"""An SB3 ``VecEnv`` over one batched ManiSkill env with dict observations."""

from __future__ import annotations

import time
from typing import Any

import gymnasium as gym
import numpy as np
import torch
from stable_baselines3.common.vec_env.base_vec_env import VecEnv


def _to_numpy(obs: Any):
    if isinstance(obs, dict):
        return {k: _to_numpy(v) for k, v in obs.items()}
    return obs.cpu().numpy() if isinstance(obs, torch.Tensor) else np.asarray(obs)


class ManiSkillDictVecEnv(VecEnv):
    """SB3 ``VecEnv`` over a batched ManiSkill env with dict observations; episodes end only at the time limit.

    ManiSkill's ``ManiSkillSB3VectorEnv`` (mani_skill/vector/wrappers/sb3.py) is the model, but in
    3.0.1 it calls ``obs.cpu()`` (flat tensors only) and puts ``info["episode"]`` into every step, so
    SB3 would log each step as a finished episode. Here: dict obs, ``episode`` / ``is_success``
    only at the end of an episode, and by default success does not end it (``ignore_terminations``):
    every episode runs ``max_episode_steps`` and the reward decides how to behave after success.
    With ``terminate_on_success`` an episode ends at its first success, as a true terminal state
    (no bootstrapping from it), the way ManiSkill's own scripts run.
    """

    def __init__(self, env: gym.Env, horizon: int, terminate_on_success: bool = False):
        u = env.unwrapped
        super().__init__(u.num_envs, env.single_observation_space, u.single_action_space)
        self._env, self.horizon, self.terminate_on_success = env, int(horizon), bool(terminate_on_success)
        self._seed = None
        self._returns = np.zeros(self.num_envs)
        self._lengths = np.zeros(self.num_envs, dtype=int)
        self._success_once = np.zeros(self.num_envs, dtype=bool)
        self.env_time = 0.0  # seconds inside the simulator (and the reward), for the speed benchmark
        self.t_start = time.time()

    @property
    def base_env(self):
        """The ManiSkill env."""
        return self._env.unwrapped

    def seed(self, seed=None):
        """Seed the next reset."""
        self._seed = seed
        return [seed] * self.num_envs

    def reset(self):
        """Reset all envs (with the seed given to ``seed`` once)."""
        obs, _ = self._env.reset(seed=self._seed)
        self._seed = None
        self._returns[:], self._lengths[:], self._success_once[:] = 0, 0, False
        return _to_numpy(obs)

    def step_async(self, actions):
        """Remember the actions for ``step_wait``."""
        self._actions = actions

    def step_wait(self):
        """Step all envs; reset those at the time limit, their last obs in ``terminal_observation``."""
        t = time.perf_counter()
        obs, rew, _terminated, truncated, info = self._env.step(torch.as_tensor(self._actions, dtype=torch.float32))
        self.env_time += time.perf_counter() - t
        rew = _to_numpy(rew).astype(np.float32).reshape(self.num_envs)
        success = _to_numpy(info["success"]).reshape(self.num_envs)
        self._returns += rew
        self._lengths += 1
        self._success_once |= success
        done = (_to_numpy(truncated).reshape(-1) if np.ndim(_to_numpy(truncated)) else np.full(self.num_envs, bool(truncated)))
        done = done | (self._lengths >= self.horizon)
        # Ended by success: a terminal state, whose value SB3 must not bootstrap (TimeLimit.truncated False).
        terminal = success.astype(bool) if self.terminate_on_success else np.zeros(self.num_envs, bool)
        done = done | terminal
        obs = _to_numpy(obs)
        infos = [{} for _ in range(self.num_envs)]
        if done.any():
            idx = np.flatnonzero(done)
            for i in idx:
                infos[i] = {"TimeLimit.truncated": not terminal[i], "is_success": bool(self._success_once[i]),
                            "episode": {"r": float(self._returns[i]), "l": int(self._lengths[i]),
                                        "t": round(time.time() - self.t_start, 6)},
                            "terminal_observation": {k: v[i].copy() for k, v in obs.items()}}
            t = time.perf_counter()
            new_obs, _ = self._env.reset(options=dict(env_idx=torch.as_tensor(idx)) if self.num_envs > 1 else None)
            self.env_time += time.perf_counter() - t
            new_obs = _to_numpy(new_obs)
            for k in obs:
                obs[k][idx] = new_obs[k][idx]
            self._returns[idx], self._lengths[idx], self._success_once[idx] = 0, 0, False
        return obs, rew, done, infos

    def close(self):
        """Close the env."""
        self._env.close()

    def get_attr(self, attr_name, indices=None):
        """An attribute of the (single, batched) env, once per sub-env."""
        return [getattr(self._env, attr_name)] * self.num_envs

    def set_attr(self, attr_name, value, indices=None):
        """Set an attribute of the env."""
        setattr(self._env, attr_name, value)

    def env_method(self, method_name, *method_args, indices=None, **method_kwargs):
        """Call a method of the env once."""
        return [getattr(self._env, method_name)(*method_args, **method_kwargs)]

    def env_is_wrapped(self, wrapper_class, indices=None):
        """Not tracked: SB3 only asks about its Monitor, which this adapter replaces."""
        return [False] * self.num_envs
