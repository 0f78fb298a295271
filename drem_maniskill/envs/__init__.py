"""ManiSkill tasks of drem-maniskill; importing this module registers them."""

from drem_maniskill.envs.agent import PandaInsertion
from drem_maniskill.envs.insertion_base import InsertionEnv
from drem_maniskill.envs.peg_in_hole import PegInHoleEnv
from drem_maniskill.envs.usb_insertion import USBInsertionEnv
from drem_maniskill.envs.aliases import DREM_ALIASES, register_drem_env  # noqa: E402  (after the tasks)

__all__ = ["InsertionEnv", "PandaInsertion", "PegInHoleEnv", "USBInsertionEnv", "DREM_ALIASES", "register_drem_env", "is_insertion_task"]


def is_insertion_task(env_id: str) -> bool:
    """Whether ``env_id`` (``module:id`` allowed) is one of our insertion tasks, not a ManiSkill task of its own."""
    from mani_skill.utils.registration import REGISTERED_ENVS

    spec = REGISTERED_ENVS.get(env_id.split(":")[-1])
    return spec is not None and issubclass(spec.cls, InsertionEnv)
