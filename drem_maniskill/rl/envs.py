"""Environments for SAC: the reward table, the policy's observation, and an SB3 VecEnv over ManiSkill.

``REWARDS`` maps a reward name to how its env is built; adding a reward is one line.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Any, Callable, Optional

import gymnasium as gym
import numpy as np
import torch
import torch.nn.functional as F
from gymnasium import spaces
from stable_baselines3.common.vec_env.base_vec_env import VecEnv


@dataclass(frozen=True)
class RewardSpec:
    """How a reward is made: the env's ``reward_mode``, extra env kwargs, an optional wrapper."""

    reward_mode: str
    env_kwargs: Callable[[str], dict] = field(default=lambda task: {})  # task -> gym.make kwargs
    wrapper: Optional[str] = None  # name of a reward wrapper (only "vice" today)
    about: str = ""


def _drem_image_kwargs(task: str) -> dict:
    from drem_maniskill.drem.reward import default_checkpoint

    path = default_checkpoint(task, image_only=True)
    if not path.exists():
        raise FileNotFoundError(
            f"reward 'drem-image' needs the image-only DREM checkpoint {path}, which is missing. Make it with "
            f"scripts/train_default_rewards.sh (it copies <out>/reward_image/drem.pt there), or by hand: "
            f"drem-maniskill train-reward --dataset <tree.h5> --modalities fixed wrist --out DIR, "
            f"then cp DIR/drem.pt {path}"
        )
    return {"drem_checkpoint": str(path)}


REWARDS: dict[str, RewardSpec] = {
    "sparse": RewardSpec("sparse", about="1 on success, else 0"),
    "dense": RewardSpec("normalized_dense", about="the task's staged dense reward in [0, 1] (ManiSkill style)"),
    "engineered": RewardSpec("engineered", about="-exp(kappa ||x - x_G||), the paper's Engineered"),
    "drem": RewardSpec("drem", about="DREM, images + F/T, rewards/<task>/drem.pt"),
    "drem-image": RewardSpec("drem", _drem_image_kwargs, about="DREM on images only, rewards/<task>/drem_image.pt"),
    # VICE replaces the reward; the env's sparse one is cheap and is kept in info["original_reward"].
    "vice": RewardSpec("sparse", wrapper="vice", about="VICE-RAQ success classifier on the images"),
}


def reward_spec(name: str) -> RewardSpec:
    """The ``REWARDS`` entry of ``name``, or a ValueError listing the choices."""
    if name not in REWARDS:
        raise ValueError(f"unknown reward {name!r}; choose one of: {', '.join(REWARDS)}")
    return REWARDS[name]


def max_episode_steps(task: str) -> int:
    """Episode length of a registered task (ManiSkill keeps it in its own registry and the gym spec)."""
    from mani_skill.utils.registration import REGISTERED_ENVS

    if task in REGISTERED_ENVS and REGISTERED_ENVS[task].max_episode_steps:
        return int(REGISTERED_ENVS[task].max_episode_steps)
    spec = gym.spec(task)
    return int(spec.max_episode_steps or spec.kwargs.get("max_episode_steps") or 50)


# ---------------------------------------------------------------------------- observation
def symlog(x: torch.Tensor) -> torch.Tensor:
    """``sign(x) log(1 + |x|)``: F/T readings span 0.1-150 N; the networks want inputs of order 1."""
    return torch.sign(x) * torch.log1p(x.abs())


class PolicyObservation(gym.ObservationWrapper):
    """ManiSkill rgb obs -> the policy's dict: uint8 ``[B, 3, S, S]`` per camera, ``ft`` ``[B, 8, 6]``, ``state``."""

    def __init__(self, env: gym.Env, image_size: int, cameras=("fixed_camera", "wrist_camera"), ft: bool = True,
                 state: bool = True):
        super().__init__(env)
        self.image_size, self.cameras, self.use_ft, self.use_state = int(image_size), tuple(cameras), ft, state
        src = env.unwrapped.single_observation_space
        single = {}
        for uid in self.cameras:
            # Channel-first uint8: SB3 then sees an image space and scales it by 1/255 without transposing.
            single[uid] = spaces.Box(0, 255, (3, self.image_size, self.image_size), np.uint8)
        if ft:
            single["ft"] = spaces.Box(-np.inf, np.inf, src["extra"]["ft"].shape, np.float32)
        if state:
            n = src["agent"]["qpos"].shape[0] + src["extra"]["tcp_pose"].shape[0]
            single["state"] = spaces.Box(-np.inf, np.inf, (n,), np.float32)
        self.single_observation_space = spaces.Dict(single)
        b = env.unwrapped.num_envs
        self.observation_space = spaces.Dict(
            {k: spaces.Box(np.broadcast_to(s.low, (b, *s.shape)), np.broadcast_to(s.high, (b, *s.shape)), (b, *s.shape), s.dtype)
             for k, s in single.items()})

    def observation(self, obs: dict) -> dict:
        """Convert one batched observation (torch tensors on the env's device)."""
        out = {}
        for uid in self.cameras:
            x = obs["sensor_data"][uid]["rgb"][..., :3].permute(0, 3, 1, 2)
            if x.shape[-1] != self.image_size:
                # Exact block means (the render is 128 px, a multiple of image_size): no aliasing of thin rims.
                k = x.shape[-1] // self.image_size
                x = F.avg_pool2d(x.float(), k).round().to(torch.uint8)
            out[uid] = x.contiguous()
        if self.use_ft:
            out["ft"] = symlog(obs["extra"]["ft"].float())
        if self.use_state:
            out["state"] = torch.cat([obs["agent"]["qpos"], obs["extra"]["tcp_pose"]], dim=-1).float()
        return out


class SharedVICEReward(gym.Wrapper):
    """Reward an env with the classifier of a training ``VICERewardWrapper`` (for evaluation; stores nothing)."""

    def __init__(self, env: gym.Env, vice):
        super().__init__(env)
        self.vice = vice

    def step(self, action):
        """Step; reward = the shared classifier's ``log p(success | s')``."""
        from drem_maniskill.baselines.vice import preprocess

        obs, reward, terminated, truncated, info = self.env.step(action)
        cfg = self.vice.config
        images = {uid: obs["sensor_data"][uid]["rgb"] for uid in cfg.cameras}
        info["original_reward"] = reward
        x = preprocess(images, cfg.cameras, cfg.image_size).to(self.vice.device)
        return obs, self.vice.classifier.log_prob(x).to(reward.device), terminated, truncated, info


STOCK_REWARDS = ("sparse", "drem")


def _make_stock_env(config, for_eval: bool):
    """A ManiSkill task of its own (e.g. PlugCharger-v1): its sparse reward, or DREM through the wrapper.

    The policy sees the task's two cameras (its fixed ``base_camera`` and wrist ``hand_camera`` in
    the roles of ours) and its state; there is no F/T sensor. Control is ``pd_ee_delta_pose``, as
    for the expert the DREM checkpoint was made from.
    """
    from drem_maniskill.drem.adapter import camera_map_for
    from drem_maniskill.drem.reward import default_checkpoint
    from drem_maniskill.drem.wrapper import DREMRewardWrapper
    from drem_maniskill.scripted import ee_control_kwargs

    if config.reward not in STOCK_REWARDS:
        raise ValueError(f"on ManiSkill's own {config.task} the rewards are {list(STOCK_REWARDS)} "
                         f"(drem: rewards/{config.task}/drem.pt), not {config.reward!r}")
    kwargs = ee_control_kwargs(config.task, config.env_kwargs)
    env = gym.make(config.task, obs_mode="rgb", reward_mode="sparse", num_envs=1 if for_eval else config.num_envs,
                   sim_backend=config.sim_backend, **kwargs)
    if config.reward == "drem":
        path = default_checkpoint(config.task)
        if not path.exists():
            env.close()
            raise FileNotFoundError(f"reward 'drem' on {config.task} needs {path}; make it with scripts/train_stock_rewards.sh {config.task}")
        env = DREMRewardWrapper(env, str(path))
    roles = camera_map_for(env.unwrapped)
    cameras = tuple(roles[r] for r in ("fixed", "wrist") if r in roles)
    return PolicyObservation(env, config.image_size, cameras, ft=False, state=config.policy_state), None


def make_env(config, vice_goal_examples=None, shared_vice=None, for_eval: bool = False):
    """The wrapped ManiSkill env of a config: ``(env, vice_wrapper_or_None)``; rgb obs rendered at 128 px."""
    import drem_maniskill  # noqa: F401  (registers the tasks)
    from drem_maniskill.envs import is_insertion_task

    if not is_insertion_task(config.task):
        return _make_stock_env(config, for_eval)
    spec = reward_spec(config.reward)
    kwargs = dict(obs_mode="rgb", reward_mode=spec.reward_mode, num_envs=1 if for_eval else config.num_envs,
                  sim_backend=config.sim_backend, **spec.env_kwargs(config.task), **config.env_kwargs)
    env = gym.make(config.task, **kwargs)
    vice = None
    if spec.wrapper == "vice":
        if shared_vice is not None:
            env = SharedVICEReward(env, shared_vice)
        else:
            from drem_maniskill.baselines.vice import VICEConfig, VICERewardWrapper, collect_goal_examples

            vcfg = VICEConfig(**{**dict(seed=config.seed), **config.vice})
            goals = vice_goal_examples
            if goals is None:
                # Goal images from the scripted expert in the training env's own look (colours, render style).
                goals = collect_goal_examples(config.task, seeds=range(config.vice_goal_seeds),
                                              env_kwargs={k: v for k, v in kwargs.items() if k not in ("num_envs", "reward_mode")},
                                              cameras=vcfg.cameras, max_steps=max_episode_steps(config.task))
            env = vice = VICERewardWrapper(env, goals, vcfg)
    env = PolicyObservation(env, config.image_size, config.cameras, ft=config.uses_ft, state=config.policy_state)
    return env, vice


# ---------------------------------------------------------------------------- SB3 adapter
def _to_numpy(obs: Any):
    if isinstance(obs, dict):
        return {k: _to_numpy(v) for k, v in obs.items()}
    return obs.cpu().numpy() if isinstance(obs, torch.Tensor) else np.asarray(obs)


class ManiSkillDictVecEnv(VecEnv):
    """SB3 ``VecEnv`` over a batched ManiSkill env with dict observations; episodes end only at the time limit.

    ManiSkill's ``ManiSkillSB3VectorEnv`` (mani_skill/vector/wrappers/sb3.py) is the model, but in
    3.0.1 it calls ``obs.cpu()`` (flat tensors only) and puts ``info["episode"]`` into every step, so
    SB3 would log each step as a finished episode. Here: dict obs, ``episode`` / ``is_success``
    only at the end of an episode, and success does not end it (``ignore_terminations``): every
    episode runs ``max_episode_steps`` and the reward decides how to behave after success.
    """

    def __init__(self, env: gym.Env, horizon: int):
        u = env.unwrapped
        super().__init__(u.num_envs, env.single_observation_space, u.single_action_space)
        self._env, self.horizon = env, int(horizon)
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
        obs = _to_numpy(obs)
        infos = [{} for _ in range(self.num_envs)]
        if done.any():
            idx = np.flatnonzero(done)
            for i in idx:
                infos[i] = {"TimeLimit.truncated": True, "is_success": bool(self._success_once[i]),
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
