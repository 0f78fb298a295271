"""An SB3 ``VecEnv`` over one batched ManiSkill env with dict observations, in this process or in a child process."""

from __future__ import annotations

import multiprocessing as mp
import signal
import time
import traceback
from typing import Any, Callable, Optional

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
        truncated = _to_numpy(truncated)
        done = truncated.reshape(-1) if np.ndim(truncated) else np.full(self.num_envs, bool(truncated))
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


# ---------------------------------------------------------------------------- the env in a child process
def _child(remote, parent_remote, build, config) -> None:
    """The child process of ``SubprocDictVecEnv``: build the run's env, then answer commands until ``close``."""
    parent_remote.close()
    # Ctrl-C reaches the whole process group: the parent stops the run and closes this process.
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        torch.set_num_threads(int(config.threads))
        venv, _ = build(config)
        remote.send(("ok", (venv.num_envs, venv.observation_space, venv.action_space)))
    except BaseException as err:  # the parent re-raises it: a missing checkpoint reads the same as in-process
        _send_error(remote, err)
        return
    while True:
        try:
            cmd, data = remote.recv()
        except EOFError:  # the parent is gone
            break
        try:
            if cmd == "step":
                venv.step_async(data)
                out = venv.step_wait()
            elif cmd == "reset":
                out = venv.reset()
            elif cmd == "seed":
                out = venv.seed(data)
            elif cmd == "getattr":
                out = getattr(venv, data)
            elif cmd == "call":
                fn, args = data
                out = fn(venv, *args)
            elif cmd == "close":
                venv.close()
                remote.send(("ok", None))
                break
            else:
                raise ValueError(f"unknown command {cmd!r}")
            remote.send(("ok", out))
        except BaseException as err:
            _send_error(remote, err)
    remote.close()


def _send_error(remote, err: BaseException) -> None:
    tb = traceback.format_exc()
    try:
        remote.send(("error", (err, tb)))
    except Exception:  # an exception that does not pickle: its traceback still does
        remote.send(("error", (None, tb)))


class SubprocDictVecEnv(VecEnv):
    """The run's ``ManiSkillDictVecEnv`` in a child process, so that SAC's gradient step and the env step overlap.

    ``step_async`` sends the actions and returns; ``step_wait`` first calls ``while_stepping`` (the
    model's deferred gradient step, ``rl.sac.SAC.train_while_env_steps``) here, then collects the
    child's step. On two cores the run then costs about max(env step, gradient step) per env step
    instead of their sum (docs/rl.md, "Speed"). SB3's own ``SubprocVecEnv`` runs one gym env per
    process and resets them itself; here one batched ManiSkill env runs in one process, with the
    episode ends of ``ManiSkillDictVecEnv``, built there by ``build(config) -> (venv, _)`` (a module-level
    function: ``rl.run_env.make_local_vec_env``). The child is started with ``spawn``: nothing of this
    process's simulator, renderer or torch threads is inherited. A learned reward (VICE-RAQ) trains on
    the run's states in this process, so its runs do not use this class (``RLConfig.overlap_env_used``).
    """

    def __init__(self, build: Callable, config, start_method: str = "spawn"):
        ctx = mp.get_context(start_method)
        self._remote, child = ctx.Pipe()
        self._proc = ctx.Process(target=_child, args=(child, self._remote, build, config), daemon=True)
        self._proc.start()
        child.close()
        self._closed = False
        try:
            num_envs, obs_space, act_space = self._recv()
        except BaseException:  # the env could not be built: the child has ended, its error is raised here
            self._closed = True
            self._proc.join(timeout=10)
            self._remote.close()
            raise
        super().__init__(num_envs, obs_space, act_space)
        self.while_stepping: Optional[Callable[[], None]] = None

    def _dead(self) -> RuntimeError:
        self._proc.join(timeout=5)
        return RuntimeError(f"the env's child process ended without an answer (exit code {self._proc.exitcode}); "
                            "its error is above, or run with overlap_env=False (--no-overlap-env) to see it here")

    def _send(self, message) -> None:
        try:
            self._remote.send(message)
        except (BrokenPipeError, ConnectionResetError):
            raise self._dead() from None

    def _recv(self):
        try:
            status, value = self._remote.recv()
        except (EOFError, ConnectionResetError):
            raise self._dead() from None
        if status == "error":
            err, tb = value
            if isinstance(err, BaseException):
                err.add_note(f"raised in the env's child process:\n{tb}")
                raise err
            raise RuntimeError(f"in the env's child process:\n{tb}")
        return value

    def _call(self, cmd: str, data=None):
        self._send((cmd, data))
        return self._recv()

    @property
    def env_time(self) -> float:
        """Seconds the child spent inside the simulator and the reward (``ManiSkillDictVecEnv.env_time``)."""
        return self._call("getattr", "env_time")

    def call(self, fn: Callable, *args):
        """``fn(child_vec_env, *args)`` run in the child (``fn`` must pickle: a module-level function); its result."""
        return self._call("call", (fn, args))

    def seed(self, seed=None):
        """Seed the child's next reset."""
        return self._call("seed", seed)

    def reset(self):
        """Reset the child's envs."""
        return self._call("reset")

    def step_async(self, actions):
        """Send the actions; the child steps while this process goes on."""
        self._send(("step", np.asarray(actions)))

    def step_wait(self):
        """Run ``while_stepping`` here while the child steps, then return the child's step."""
        if self.while_stepping is not None:
            self.while_stepping()
        return self._recv()

    def close(self):
        """Close the child's env and end the process."""
        if self._closed:
            return
        self._closed = True
        try:
            if self._proc.is_alive():
                self._call("close")
        except (RuntimeError, BrokenPipeError, OSError):
            pass
        self._proc.join(timeout=10)
        if self._proc.is_alive():
            self._proc.terminate()
        self._remote.close()

    def get_attr(self, attr_name, indices=None):
        """An attribute of the child's ``ManiSkillDictVecEnv``, once per sub-env."""
        return [self._call("getattr", attr_name)] * self.num_envs

    def set_attr(self, attr_name, value, indices=None):
        """Not supported across the process boundary."""
        raise NotImplementedError("SubprocDictVecEnv does not set attributes in its child; use call()")

    def env_method(self, method_name, *method_args, indices=None, **method_kwargs):
        """Not supported across the process boundary (``call`` runs a module-level function there)."""
        raise NotImplementedError("SubprocDictVecEnv has no env_method; use call() with a module-level function")

    def env_is_wrapped(self, wrapper_class, indices=None):
        """Not tracked, as in ``ManiSkillDictVecEnv``."""
        return [False] * self.num_envs
