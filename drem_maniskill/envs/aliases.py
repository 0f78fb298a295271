"""Env ids whose default reward is DREM, for scripts that take no reward flag.

ManiSkill's baselines (``ppo.py``, ``ppo_cpu.py``, ``sac.py``) and its benchmark runner make
``gym.make(env_id, ...)`` without a reward mode, so they train on the env's default. These ids
make that default DREM:

* ``PegInHole-DREM-v1``, ``USBInsertion-DREM-v1``: our tasks with ``reward_mode="drem"`` by
  default and the shipped checkpoint (``drem_checkpoint=`` picks another); every other reward
  mode stays available;
* ``register_drem_env("PegInsertionSide-v1", "ckpt.pt")`` registers ``PegInsertionSide-DREM-v1``:
  a stock ManiSkill task with a ``drem`` reward mode added and made the default, reading the
  checkpoint's cameras (rendered once per step when the obs has no images).

The aliases are subclasses registered in ManiSkill's registry (not gymnasium wrappers), so
``ManiSkillVectorEnv``, ``CPUGymWrapper`` and the GPU sim treat them as ordinary ManiSkill envs,
and ``info["success"]`` is the task's own. Their ``env_id`` stays the base task's, so
checkpoints trained on the base task fit.
"""

from __future__ import annotations

from pathlib import Path
from typing import Optional

from mani_skill.utils.registration import REGISTERED_ENVS, register_env

from drem_maniskill.envs.peg_in_hole import PegInHoleEnv
from drem_maniskill.envs.usb_insertion import USBInsertionEnv

DREM_ALIASES = {"PegInHole-DREM-v1": "PegInHole-v1", "USBInsertion-DREM-v1": "USBInsertion-v1"}


def _drem_default(base_cls, alias: str):
    class DREMDefault(base_cls):
        __doc__ = f"{base_cls.__name__} with reward_mode='drem' by default ({alias})."

        def __init__(self, *args, reward_mode: Optional[str] = "drem", **kwargs):
            super().__init__(*args, reward_mode=reward_mode, **kwargs)

    DREMDefault.__name__ = DREMDefault.__qualname__ = f"{base_cls.__name__}DREM"
    return DREMDefault


for _alias, _base, _cls in (("PegInHole-DREM-v1", "PegInHole-v1", PegInHoleEnv),
                            ("USBInsertion-DREM-v1", "USBInsertion-v1", USBInsertionEnv)):
    register_env(_alias, max_episode_steps=REGISTERED_ENVS[_base].max_episode_steps)(_drem_default(_cls, _alias))


def register_drem_env(base_env_id: str, checkpoint: str, new_env_id: Optional[str] = None) -> str:
    """Register ``<Base>-DREM-vN``: a stock ManiSkill task whose default reward is DREM from ``checkpoint``."""
    from drem_maniskill.drem.checkpoint import load_checkpoint

    if base_env_id not in REGISTERED_ENVS:
        raise ValueError(f"{base_env_id!r} is not a registered ManiSkill env id")
    header, _ = load_checkpoint(checkpoint)  # fails clearly on a missing or corrupt file, now
    if header.get("env_id") != base_env_id:
        raise ValueError(f"{checkpoint} was trained on {header.get('env_id')!r}, not {base_env_id!r}")
    spec = REGISTERED_ENVS[base_env_id]
    base = spec.cls
    if new_env_id is None:
        name, sep, version = base_env_id.rpartition("-v")
        new_env_id = f"{name}-DREM-v{version}" if sep else f"{base_env_id}-DREM"
    default_checkpoint = str(Path(checkpoint).resolve())

    class StockDREM(base):
        SUPPORTED_REWARD_MODES = tuple(base.SUPPORTED_REWARD_MODES) + ("drem",)
        env_id = base_env_id  # what the checkpoint's header must name

        def __init__(self, *args, reward_mode: Optional[str] = "drem", drem_checkpoint: str = default_checkpoint, **kwargs):
            self.drem_checkpoint = drem_checkpoint
            self._drem = None
            super().__init__(*args, reward_mode=reward_mode, **kwargs)

        def get_reward(self, obs, action, info):
            """DREM ``R(s)`` when ``reward_mode="drem"``, else the task's own reward."""
            if self.reward_mode != "drem":
                return super().get_reward(obs, action, info)
            from drem_maniskill.drem.adapter import adapter_for
            from drem_maniskill.drem.reward import DREMReward

            if self._drem is None:
                self._drem = DREMReward.from_checkpoint(self.drem_checkpoint, env=self)
                self._adapter = adapter_for(self)
            images = self._adapter.images(obs)
            batch = {m: images[m] for m in self._drem.model.config.cameras}
            return self._drem(batch).to(self.device)

    StockDREM.__name__ = StockDREM.__qualname__ = f"{base.__name__}DREM"
    # Registering the same id again (another checkpoint) replaces the old one.
    register_env(new_env_id, max_episode_steps=spec.max_episode_steps, override=True)(StockDREM)
    return new_env_id
