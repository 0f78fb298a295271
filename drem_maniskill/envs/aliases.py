"""Env ids whose default reward is DREM, for scripts that take no reward flag.

ManiSkill's baselines (``ppo.py``, ``ppo_cpu.py``, ``sac.py``) and its benchmark runner make
``gym.make(env_id, ...)`` without a reward mode, so they train on the env's default. These ids
make that default DREM:

* ``PegInHole-DREM-v1``, ``USBInsertion-DREM-v1`` (one per task of ``envs.TASKS``): our tasks with
  ``reward_mode="drem"`` by default and the shipped checkpoint (``drem_checkpoint=`` picks another), paying ``R - 1``
  (``drem_form="shifted"``, safe where success ends the episode; ``drem_form="paper"`` pays ``R``);
  every other reward mode stays available;
* ``register_drem_env("PegInsertionSide-v1", "ckpt.pt")`` registers ``PegInsertionSide-DREM-v1``:
  a stock ManiSkill task with a ``drem`` reward mode added and made the default, reading the
  checkpoint's cameras (rendered once per step when the obs has no images).

Why subclasses and not ``DREMRewardWrapper`` in the registry: ``register_env`` registers a
``BaseEnv`` subclass (it refuses anything else), and gymnasium's entry point is ManiSkill's
``make``, which instantiates that class. ManiSkill's scripts then wrap what ``gym.make`` returns
(``ManiSkillVectorEnv``, ``CPUGymWrapper``, ``FlattenRGBDObservationWrapper``,
``RecordEpisode``) and several of them read ``env.unwrapped`` (reward mode, ``num_envs``,
device, ``_sensors``): a gymnasium wrapper under those would be skipped by ``.unwrapped`` and
would change the order of wrappers the scripts expect. A subclass keeps the env a plain
ManiSkill env whose ``get_reward`` gives DREM, so the batched reward tensor, ``info["success"]``
(the task's own ``evaluate``), the GPU sim and the time limit behave as on the base task. The
``drem`` mode is ``drem_maniskill.drem.mode.DREMRewardMode``, the same mixin our tasks use,
so the checkpoint's checks and inputs are the same on every route. The aliases' ``env_id`` stays
the base task's, so checkpoints trained on the base task fit.
"""

from __future__ import annotations

from pathlib import Path
from typing import Optional

from mani_skill.utils.registration import REGISTERED_ENVS, register_env

from drem_maniskill.drem.checkpoint import load_checkpoint, resolve_checkpoint
from drem_maniskill.drem.mode import DREMRewardMode


def drem_env_id(base_env_id: str) -> str:
    """The DREM-by-default id of ``base_env_id``: ``-DREM`` before its last ``-vN`` suffix."""
    # Naming: ManiSkill ids are <Task>-v<N>; the reward goes into the task part, the version stays.
    name, sep, version = base_env_id.rpartition("-v")
    return f"{name}-DREM-v{version}" if sep and version.isdigit() else f"{base_env_id}-DREM"


def _drem_default(base_cls, alias: str, checkpoint: Optional[str] = None):
    """``base_cls`` with ``reward_mode="drem"`` by default, reading ``checkpoint`` (None: the shipped one)."""

    class DREMDefault(base_cls):
        __doc__ = (f"{base_cls.__name__} with reward_mode='drem' by default ({alias}), "
                   "paying R - 1 (drem_form='shifted').")

        # ManiSkill's scripts end episodes at success; the paper's R (positive per step) then pays an agent for
        # never finishing (measured: docs/maniskill-scripts.md). R - 1 is never positive: finishing costs nothing.
        def __init__(self, *args, reward_mode: Optional[str] = "drem",
                     drem_checkpoint: Optional[str] = checkpoint, drem_form: str = "shifted", **kwargs):
            super().__init__(*args, reward_mode=reward_mode, drem_checkpoint=drem_checkpoint, drem_form=drem_form,
                             **kwargs)

    DREMDefault.__name__ = DREMDefault.__qualname__ = f"{base_cls.__name__}DREM"
    return DREMDefault


def register_task_aliases(tasks) -> dict:
    """Register ``<Task>-DREM-v<N>`` for each of our ``tasks``; returns alias -> task."""
    aliases = {}
    for task in tasks:
        spec = REGISTERED_ENVS[task]
        alias = drem_env_id(task)
        register_env(alias, max_episode_steps=spec.max_episode_steps)(_drem_default(spec.cls, alias))
        aliases[alias] = task
    return aliases


def register_drem_env(base_env_id: str, checkpoint: Optional[str] = None, new_env_id: Optional[str] = None,
                      **kwargs) -> str:
    """Register a ManiSkill task with DREM from ``checkpoint`` (None: the shipped one) as its default reward.

    Returns the new id.
    """
    if base_env_id not in REGISTERED_ENVS:
        raise ValueError(f"{base_env_id!r} is not a registered ManiSkill env id")
    checkpoint = resolve_checkpoint(base_env_id, checkpoint)
    header, _ = load_checkpoint(checkpoint)  # fails clearly on a corrupt file, now
    if header.get("env_id") != base_env_id:
        raise ValueError(f"{checkpoint} was trained on {header.get('env_id')!r}, not {base_env_id!r}")
    spec = REGISTERED_ENVS[base_env_id]
    base = spec.cls
    new_env_id = new_env_id or drem_env_id(base_env_id)
    if issubclass(base, DREMRewardMode):
        cls = _drem_default(base, new_env_id, str(Path(checkpoint).resolve()))
    else:

        class StockDREM(DREMRewardMode, base):
            SUPPORTED_REWARD_MODES = tuple(base.SUPPORTED_REWARD_MODES) + ("drem",)
            env_id = base_env_id  # what the checkpoint's header must name

        StockDREM.__name__ = StockDREM.__qualname__ = f"{base.__name__}WithDREM"
        # Absolute: a script may chdir, and worker processes may start elsewhere.
        cls = _drem_default(StockDREM, new_env_id, str(Path(checkpoint).resolve()))
        cls.__name__ = cls.__qualname__ = f"{base.__name__}DREM"
    cls.__doc__ = f"{base.__name__} with a 'drem' reward mode, the default, from {Path(checkpoint).resolve()}."
    # Registering the same id again (another checkpoint) replaces the old one. The base spec's
    # default kwargs come first so the alias makes the same env as the base id.
    register_env(new_env_id, max_episode_steps=spec.max_episode_steps, override=True,
                 asset_download_ids=list(spec.asset_download_ids or []), **{**spec.default_kwargs, **kwargs})(cls)
    return new_env_id
