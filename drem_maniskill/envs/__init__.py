"""ManiSkill tasks of drem-maniskill; importing this module registers them."""

from drem_maniskill.envs.agent import PandaInsertion
from drem_maniskill.envs.insertion_base import InsertionEnv
from drem_maniskill.envs.peg_in_hole import PegInHoleEnv
from drem_maniskill.envs.usb_insertion import USBInsertionEnv
from drem_maniskill.envs.aliases import DREM_ALIASES, register_drem_env  # noqa: E402  (after the tasks)

__all__ = ["InsertionEnv", "PandaInsertion", "PegInHoleEnv", "USBInsertionEnv", "DREM_ALIASES", "register_drem_env"]
