"""A gymnasium wrapper that gives any ManiSkill env a DREM reward from a checkpoint.

``DREMRewardWrapper(gym.make("PegInsertionSide-v1", ...), checkpoint)`` replaces the env's
reward with ``R(s)`` of a checkpoint trained on that env and keeps the original reward in
``info["original_reward"]``. The inputs are built by ``DREMReward.reward(env, obs)``, as inside
the ``drem`` reward mode: camera images from the observation when it has them, else the
checkpoint's cameras rendered once per step; the F/T modality needs our wrist sensor
(``env.unwrapped.ft``).

``reward_read_at_end(env)`` runs an env's steps without its DREM reward and reads the reward once, where a caller
needs only the last one (the end of a hold, of an expert's episode): a step's DREM reward renders the cameras.
"""

from __future__ import annotations

from contextlib import contextmanager

import gymnasium as gym
import torch

from drem_maniskill.drem.guard import SupportGuard
from drem_maniskill.drem.reward import DREMReward, apply_form, check_form


class DREMRewardWrapper(gym.Wrapper):
    """Replace a ManiSkill env's reward with a DREM reward; the old one goes to ``info``.

    ``form``: one of ``drem.reward.DREM_FORMS``.
    """

    def __init__(self, env: gym.Env, checkpoint: str, form: str = "paper"):
        super().__init__(env)
        self.form = check_form(form)
        self.reward_model = DREMReward.from_checkpoint(str(checkpoint), env=env)
        self.paused = False  # steps pay 0 and compute nothing (``reward_read_at_end``)

    def reward(self, obs) -> torch.Tensor:
        """DREM reward ``[num_envs]`` of the env's current state, in this wrapper's form."""
        return apply_form(self.reward_model.reward(self.env, obs), self.form)

    def step(self, action):
        """Step the env; reward replaced by DREM, original kept in ``info["original_reward"]``."""
        obs, reward, terminated, truncated, info = self.env.step(action)
        info["original_reward"] = reward
        if self.paused:
            return obs, torch.zeros_like(torch.as_tensor(reward), dtype=torch.float32), terminated, truncated, info
        return obs, self.reward(obs), terminated, truncated, info


def drem_source(env: gym.Env):
    """What pays ``env``'s reward when it is a DREM reward: the ``DREMRewardWrapper`` in its wrapper chain, else the
    task itself in the ``drem`` mode; None where neither does, or where a wrapper changes the DREM reward on its way
    out (``SupportGuard``, a ``gym.RewardWrapper``), so that one read of R is not what a step pays."""
    e = env
    while isinstance(e, gym.Wrapper):
        if isinstance(e, DREMRewardWrapper):
            return e
        if isinstance(e, (SupportGuard, gym.RewardWrapper)):
            return None
        e = e.env
    u = env.unwrapped
    return u if getattr(u, "reward_mode", None) == "drem" and getattr(u, "drem_reward", None) is not None else None


@contextmanager
def reward_read_at_end(env: gym.Env):
    """Within it ``env``'s steps skip its DREM reward (they pay 0 and render nothing for it); yields ``read()``: R
    ``[num_envs]`` of the env's current state in the env's form, what a step ending there pays.

    The F/T history and the state do not depend on the reward, so a read after the last step equals that step's
    reward. ``env``'s reward must be a DREM reward (``drem_source``), else a ValueError.
    """
    source = drem_source(env)
    if source is None:
        raise ValueError("reward_read_at_end needs an env paid by a DREM reward (reward_mode='drem' or "
                         "DREMRewardWrapper) with nothing changing it on the way out")
    if isinstance(source, DREMRewardWrapper):
        source.paused = True
        try:
            yield lambda: source.reward(None)
        finally:
            source.paused = False
        return
    mode = source.reward_mode
    source._reward_mode = "none"  # ManiSkill's own switch: get_reward pays zeros
    try:
        yield lambda: source.compute_drem_reward(obs=None, action=None, info=None)
    finally:
        source._reward_mode = mode
