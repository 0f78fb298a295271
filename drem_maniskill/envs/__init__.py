"""ManiSkill tasks of drem-maniskill; importing this module registers them.

``TASKS`` is the one task list: every part of the package (the demo, the DREM aliases, the
scripts, the docs pictures, the tests) reads it. Adding a task is one task file here, one line
in ``TASK_FILES`` and its data (``tasks/<id>/`` expert demo, ``rewards/<id>/`` checkpoint); see
docs/architecture.md.
"""

from __future__ import annotations

import difflib
import importlib

from mani_skill.utils.registration import REGISTERED_ENVS

from drem_maniskill.envs.agent import PandaInsertion
from drem_maniskill.envs.aliases import drem_env_id, register_drem_env, register_task_aliases
from drem_maniskill.envs.insertion_base import InsertionEnv
from drem_maniskill.envs.rendering import install as _install_blank_brdf_lut

# Every ManiSkill env made in this process skips SAPIEN's BRDF table where it cannot change a pixel (envs.rendering).
_install_blank_brdf_lut()

# The one task list: env id -> the module of its task file in this folder (which registers the
# task with ManiSkill's @register_env).
TASK_FILES = {
    "PegInHole-v1": "peg_in_hole",
    "USBInsertion-v1": "usb_insertion",
    "SquarePegInHole-v1": "square_peg_in_hole",
    "DPegInHole-v1": "d_peg_in_hole",
    "HexPegInTiltedHole-v1": "hex_peg_in_tilted_hole",
}


def load_tasks(task_files: dict) -> dict:
    """Import each task file (registering its task) and register the task's ``-DREM`` alias; returns alias -> task."""
    for module in task_files.values():
        importlib.import_module(f"{__name__}.{module}")
    return register_task_aliases(task_files)


DREM_ALIASES = load_tasks(TASK_FILES)
TASKS = tuple(TASK_FILES)

from drem_maniskill.envs.peg_in_hole import PegInHoleEnv  # noqa: E402  (registered above)
from drem_maniskill.envs.usb_insertion import USBInsertionEnv  # noqa: E402

__all__ = ["TASKS", "TASK_FILES", "InsertionEnv", "PandaInsertion", "PegInHoleEnv", "USBInsertionEnv", "DREM_ALIASES",
           "drem_env_id", "register_drem_env", "load_tasks", "is_insertion_task", "UnknownTaskError", "check_env_id"]


class UnknownTaskError(ValueError):
    """An env id that neither we nor ManiSkill registered."""


def is_insertion_task(env_id: str) -> bool:
    """Whether ``env_id`` (``module:id`` allowed) is one of our insertion tasks, not a ManiSkill task of its own."""
    spec = REGISTERED_ENVS.get(env_id.split(":")[-1])
    return spec is not None and issubclass(spec.cls, InsertionEnv)


def check_env_id(env_id: str) -> str:
    """``env_id`` if ManiSkill's registry knows it (``module:id`` allowed).

    Otherwise ``UnknownTaskError`` listing the ids.
    """
    if env_id.split(":")[-1] in REGISTERED_ENVS:
        return env_id
    ours = list(TASKS) + list(DREM_ALIASES)
    others = sorted(set(REGISTERED_ENVS) - set(ours))
    close = difflib.get_close_matches(env_id.split(":")[-1], list(REGISTERED_ENVS), n=3)
    raise UnknownTaskError(
        f"unknown task id {env_id!r}. Ours: {', '.join(ours)}; ManiSkill's: {', '.join(others)}"
        + (f". Did you mean {' or '.join(close)}?" if close else "")
    )
