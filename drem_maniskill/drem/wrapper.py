"""A gymnasium wrapper that gives any ManiSkill env a DREM reward from a checkpoint.

``DREMRewardWrapper(gym.make("PegInsertionSide-v1", ...), checkpoint)`` replaces the env's
reward with ``R(s)`` of a checkpoint trained on that env and keeps the original reward in
``info["original_reward"]``. The inputs are built by ``DREMReward.reward(env, obs)``, as inside
the ``drem`` reward mode: camera images from the observation when it has them, else the
checkpoint's cameras rendered once per step; the F/T modality needs our wrist sensor
(``env.unwrapped.ft``).
"""

from __future__ import annotations

import gymnasium as gym
import torch

from drem_maniskill.drem.reward import DREMReward, apply_form, check_form


class DREMRewardWrapper(gym.Wrapper):
    """Replace a ManiSkill env's reward with a DREM reward; the old one goes to ``info``.

    ``form``: one of ``drem.reward.DREM_FORMS``.
    """

    def __init__(self, env: gym.Env, checkpoint: str, form: str = "paper"):
        super().__init__(env)
        self.form = check_form(form)
        self.reward_model = DREMReward.from_checkpoint(str(checkpoint), env=env)

    def reward(self, obs) -> torch.Tensor:
        """DREM reward ``[num_envs]`` of the env's current state, in this wrapper's form."""
        return apply_form(self.reward_model.reward(self.env, obs), self.form)

    def step(self, action):
        """Step the env; reward replaced by DREM, original kept in ``info["original_reward"]``."""
        obs, reward, terminated, truncated, info = self.env.step(action)
        info["original_reward"] = reward
        return obs, self.reward(obs), terminated, truncated, info
