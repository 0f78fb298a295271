"""Compatibility shims for ManiSkill 3.0.x that our observations need.

Our ``obs["extra"]["ft"]`` is a ``[num_envs, history, 6]`` tensor. ManiSkill's
``flatten_state_dict`` (used by the ``state`` obs mode and by ``FlattenRGBDObservationWrapper``)
only accepts tensors of at most 2 dims and fails on it. We wrap it so that tensors with more
dims are flattened to ``[num_envs, -1]``; every input the original accepted gives the same
result as before.
"""

from __future__ import annotations

import torch

from mani_skill.utils import common

_original_flatten_state_dict = common.flatten_state_dict


def _flatten_batched(value):
    if isinstance(value, dict):
        return {k: _flatten_batched(v) for k, v in value.items()}
    if isinstance(value, torch.Tensor) and value.ndim > 2:
        return value.reshape(value.shape[0], -1)
    return value


def flatten_state_dict(state_dict: dict, use_torch=False, device=None):
    """ManiSkill's ``flatten_state_dict`` that also takes ``[B, ...]`` tensors of any rank."""
    return _original_flatten_state_dict(_flatten_batched(state_dict), use_torch=use_torch, device=device)


if getattr(common.flatten_state_dict, "__module__", "") != __name__:
    common.flatten_state_dict = flatten_state_dict
