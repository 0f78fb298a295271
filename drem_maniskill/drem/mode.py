"""The ``drem`` reward mode of a ManiSkill task: one mixin, used by our tasks and by ``register_drem_env``.

``class MyTask(DREMRewardMode, BaseEnv)`` gives a task the ``drem_checkpoint`` kwarg and, with
``reward_mode="drem"``, loads the checkpoint once at construction (``drem_checkpoint``, else the
shipped ``rewards/<env_id>/drem.pt``), checks it against the env (cameras, F/T, env id) so a
checkpoint that does not fit fails at ``gym.make``, and answers ``get_reward`` with
``DREMReward.reward(self, obs)``. The task lists ``"drem"`` in its ``SUPPORTED_REWARD_MODES``.

An unknown ``reward_mode`` raises ``UnsupportedModeError``: a ``NotImplementedError``, which is
what ManiSkill's own tasks raise (and what its tools catch), and a ``ValueError``, with the
choices in the message.
"""

from __future__ import annotations

from typing import Any, Optional

import torch

from drem_maniskill.drem.checkpoint import resolve_checkpoint
from drem_maniskill.drem.reward import DREMReward, apply_form, check_form


class UnsupportedModeError(NotImplementedError, ValueError):
    """An unknown mode (reward, obs or control).

    ManiSkill's ``NotImplementedError``, with a message that names the fix.
    """


class DREMRewardMode:
    """Mixin for a ManiSkill ``BaseEnv`` subclass: reward mode ``drem``, kwargs ``drem_checkpoint``, ``drem_form``.

    ``drem_form`` (``drem.reward.DREM_FORMS``): ``"paper"`` pays ``R(s)``, ``"shifted"`` ``R(s) - 1``
    (never positive: safe where success ends the episode).
    """

    env_id: str = ""  # the registered id a checkpoint's header must name

    def __init__(self, *args, reward_mode: Optional[str] = None, drem_checkpoint: Optional[str] = None,
                 drem_form: str = "paper", **kwargs):
        if reward_mode is not None and reward_mode not in self.SUPPORTED_REWARD_MODES:
            raise UnsupportedModeError(
                f"Unknown reward_mode {reward_mode!r} for {type(self).__name__}. "
                f"Choose one of {list(self.SUPPORTED_REWARD_MODES)}, e.g. gym.make(..., reward_mode='dense')."
            )
        self.drem_checkpoint = drem_checkpoint
        self.drem_form = check_form(drem_form)
        self.drem_reward: Optional[DREMReward] = None
        super().__init__(*args, reward_mode=reward_mode, **kwargs)
        if self.reward_mode == "drem":
            path = resolve_checkpoint(self.env_id, drem_checkpoint)
            self.drem_reward = DREMReward.from_checkpoint(str(path), env=self)

    def compute_drem_reward(self, obs: Any, action: torch.Tensor, info: dict) -> torch.Tensor:
        """DREM task progress ``R(s)`` (Eq. 2) of the current state, ``[num_envs]``, in the env's ``drem_form``."""
        return apply_form(self.drem_reward.reward(self, obs), self.drem_form)

    def get_reward(self, obs: Any, action: torch.Tensor, info: dict):
        """``compute_drem_reward`` when ``reward_mode="drem"``, else the task's own reward."""
        if self.reward_mode == "drem":
            return self.compute_drem_reward(obs=obs, action=action, info=info).to(self.device)
        return super().get_reward(obs, action, info)
