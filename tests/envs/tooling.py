"""Constants and helpers of the tests of ManiSkill's own tooling on our task ids (tests/envs/test_*)."""

from __future__ import annotations

import os
import subprocess
import sys
import warnings

import gymnasium as gym
import torch
from mani_skill.utils.registration import REGISTERED_ENVS

import drem_maniskill  # noqa: F401  (registers the tasks; conftest imports it too)
from drem_maniskill.envs import TASKS

ENV_ID = "PegInHole-v1"
IDS = {task: REGISTERED_ENVS[task].cls for task in TASKS}
CAMERAS = ("fixed_camera", "wrist_camera")
IMG = 128
FT_HISTORY = 8
# Layout of the flat "state" obs (ManiSkill flattens the obs dict in insertion order):
# agent.qpos 9, agent.qvel 9, extra.tcp_pose 7, extra.ft 8*6, extra.part_pose 7,
# extra.socket_pose 7, extra.tip_in_socket 3.
QPOS, QVEL, TCP = slice(0, 9), slice(9, 18), slice(18, 25)
FT = slice(25, 25 + 6 * FT_HISTORY)
PART_POSE = slice(73, 80)
STATE_DIM = 90
SUBPROCESS_TIMEOUT = 300
# An accelerating hand: the wrist reads the inertia of what it holds. At rest in free space it
# reads 0 (gravity is off for robot links, and the fingers rest on the part without squeezing it).
MOVE = torch.full((1, 6), 0.5)

def make_quiet(obs_mode: str, **kwargs):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return gym.make(ENV_ID, obs_mode=obs_mode, **kwargs)


def leaves(tree, prefix=""):
    """``{"a/b": leaf}`` for a nested dict (or a gym Dict space)."""
    out = {}
    items = tree.spaces.items() if isinstance(tree, gym.spaces.Dict) else tree.items()
    for key, value in items:
        if isinstance(value, (dict, gym.spaces.Dict)):
            out.update(leaves(value, f"{prefix}{key}/"))
        else:
            out[f"{prefix}{key}"] = value
    return out


def ft_buffer(env) -> torch.Tensor:
    """The env's F/T history ``[num_envs, 8, 6]``."""
    return env.unwrapped.ft.buffer


def run_subprocess(args, cwd, timeout=SUBPROCESS_TIMEOUT):
    env = dict(os.environ, PYTHONWARNINGS="ignore")
    proc = subprocess.run(
        [sys.executable, *args], cwd=cwd, env=env, capture_output=True, text=True, timeout=timeout
    )
    return proc


def fail_msg(proc) -> str:
    return f"exit {proc.returncode}\n--- stdout\n{proc.stdout[-4000:]}\n--- stderr\n{proc.stderr[-4000:]}"
