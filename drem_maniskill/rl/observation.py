"""The policy's observation: ManiSkill's observation as SB3 wants it (channel-first uint8 cameras, F/T, state)."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import torch
import torch.nn.functional as F
from gymnasium import spaces


def symlog(x: torch.Tensor) -> torch.Tensor:
    """``sign(x) log(1 + |x|)``: F/T readings span 0.1-150 N; the networks want inputs of order 1."""
    return torch.sign(x) * torch.log1p(x.abs())


def state_parts(qvel: bool = False, privileged: bool = False) -> tuple:
    """The ``(group, key)`` pairs of ManiSkill's obs dict that make the policy's ``state`` vector, in order.

    Never ``tip_in_socket`` or anything else the rewards are computed from: a policy that saw the
    engineered reward's input would make the comparison of rewards unfair.
    """
    parts = [("agent", "qpos")] + ([("agent", "qvel")] if qvel else []) + [("extra", "tcp_pose")]
    return tuple(parts + ([("extra", "socket_pose")] if privileged else []))


def task_state_parts(extra_space: spaces.Dict) -> tuple:
    """ManiSkill's own task state (object and goal poses: ``obs["extra"]`` but the TCP pose), what its state
    observation gives every policy; the privileged state of a policy on a stock task."""
    return tuple(("extra", key) for key in extra_space.spaces if key != "tcp_pose")


class PolicyObservation(gym.ObservationWrapper):
    """ManiSkill obs -> the policy's dict: uint8 ``[B, 3, S, S]`` per camera, ``ft`` ``[B, 8, 6]``, ``state``."""

    def __init__(self, env: gym.Env, image_size: int, cameras=("fixed_camera", "wrist_camera"), ft: bool = True,
                 state: bool = True, state_keys: tuple = state_parts()):
        super().__init__(env)
        self.image_size, self.cameras, self.use_ft, self.use_state = int(image_size), tuple(cameras), ft, state
        src = env.unwrapped.single_observation_space
        missing = [f"{g}/{k}" for g, k in state_keys if k not in src[g].spaces] if state else []
        if missing:
            raise ValueError(f"the policy's state needs {missing}, which {env.unwrapped.spec.id} does not observe "
                             f"(obs_mode={env.unwrapped.obs_mode!r})")
        self.state_keys = tuple(state_keys)
        single = {}
        for uid in self.cameras:
            # Channel-first uint8: SB3 then sees an image space and scales it by 1/255 without transposing.
            single[uid] = spaces.Box(0, 255, (3, self.image_size, self.image_size), np.uint8)
        if ft:
            single["ft"] = spaces.Box(-np.inf, np.inf, src["extra"]["ft"].shape, np.float32)
        if state:
            n = sum(int(np.prod(src[g][k].shape)) for g, k in self.state_keys)  # scalars, e.g. a hole's radius
            single["state"] = spaces.Box(-np.inf, np.inf, (n,), np.float32)
        self.single_observation_space = spaces.Dict(single)
        b = env.unwrapped.num_envs
        self.observation_space = spaces.Dict(
            {k: spaces.Box(np.broadcast_to(s.low, (b, *s.shape)), np.broadcast_to(s.high, (b, *s.shape)),
                           (b, *s.shape), s.dtype)
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
            b = self.env.unwrapped.num_envs
            out["state"] = torch.cat([obs[g][k].float().reshape(b, -1) for g, k in self.state_keys], dim=-1)
        return out
