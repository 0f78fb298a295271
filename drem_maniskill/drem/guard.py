"""A guard on the DREM reward off the progress tree's support (not in the paper).

DREM's progress is learned from the tree's nodes only; a state unlike any of them gets an
embedding the triplet loss never constrained. SAC finds such states: on PegInHole-v1 it pressed
the peg onto the floor and dragged it away from the socket, where the reward pays 0.83-0.96,
about what an insertion pays (docs/results.md). The model's own decoders tell such states
apart: their fixed-camera reconstruction error was 3-5 times that of any in-tree behaviour.

``pipeline.support.calibrate_support`` reads the per-camera reconstruction errors of every tree
node and keeps a high quantile ``tau`` of each (``GUARD_QUANTILE``); ``SupportGuard`` multiplies the reward by
``w = clip(2 - e / tau, 0, 1)`` (the smallest over the cameras): 1 where a state reconstructs
as well as the tree's nodes, falling to 0 at twice the tree's error.
"""

from __future__ import annotations

import json
from pathlib import Path

import gymnasium as gym
import torch

from drem_maniskill.drem.model import DREMModel

GUARD_QUANTILE = 0.999


@torch.no_grad()
def image_errors(model: DREMModel, batch: dict) -> dict:
    """Per camera, the mean squared error ``[B]`` of the decoded image against the input.

    ``batch`` holds raw inputs, as the reward takes them, F/T too.
    """
    inputs = model.prepare(batch)
    recon = model.decode(model.encode(inputs))
    return {c: (torch.sigmoid(recon[c]) - inputs[c]).pow(2).mean(dim=(1, 2, 3)) for c in model.config.cameras}


def guard_weight(errors: dict, tau: dict) -> torch.Tensor:
    """``min over cameras of clip(2 - e / tau, 0, 1)`` ``[B]``."""
    w = [torch.clamp(2.0 - e / float(tau[c]), 0.0, 1.0) for c, e in errors.items()]
    return torch.stack(w).min(dim=0).values


class SupportGuard(gym.Wrapper):
    """Multiplies a DREM env's reward by ``guard_weight``; ``info["drem_support"]`` holds the weight.

    ``env`` is one of our tasks in ``reward_mode="drem"`` (its ``drem_reward`` is read), and
    ``tau`` the per-camera errors of ``calibrate_support`` (``rewards/<task>/support.json``).
    """

    def __init__(self, env: gym.Env, tau: dict):
        super().__init__(env)
        self.drem = env.unwrapped.drem_reward
        missing = set(self.drem.model.config.cameras) - set(tau)
        if missing:
            raise ValueError(f"support guard has no threshold for cameras {sorted(missing)}; re-run its calibration")
        self.tau = {c: float(tau[c]) for c in self.drem.model.config.cameras}

    def step(self, action):
        """Step, then scale the reward by how well the state reconstructs."""
        obs, reward, terminated, truncated, info = self.env.step(action)
        # The images the reward was just computed from: rendering them again would cost as much as the step.
        w = guard_weight(image_errors(self.drem.model, self.drem.last_inputs), self.tau).to(reward.device)
        info["drem_support"] = w
        return obs, reward * w, terminated, truncated, info


def load_support(path) -> dict:
    """The ``tau`` of a ``support.json``."""
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"{path} is missing; make it with `drem-maniskill calibrate-support`")
    return json.loads(path.read_text())["tau"]
