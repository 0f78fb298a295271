"""Env states as nested dicts of batched tensors: flatten, unflatten, pick one step, broadcast."""

from __future__ import annotations

import torch


def first_leaf(tree: dict):
    """The first non-dict value of a nested dict."""
    value = next(iter(tree.values()))
    return first_leaf(value) if isinstance(value, dict) else value


def state_at(states: dict, index: int) -> dict:
    """Step ``index`` of a recorded state tree (every leaf ``[T, ...]``), as a batch of one."""
    return {k: (state_at(v, index) if isinstance(v, dict) else torch.as_tensor(v[index : index + 1]))
            for k, v in states.items()}


def broadcast_state(state: dict, n: int) -> dict:
    """A batch-of-one state repeated to ``n`` envs (copies, so the envs can diverge)."""
    def repeat(v):
        v = torch.as_tensor(v)
        return v.expand(n, *v.shape[1:]).clone()

    return {k: (broadcast_state(v, n) if isinstance(v, dict) else repeat(v)) for k, v in state.items()}


def flatten_state(state: dict) -> torch.Tensor:
    """Flat ``[B, D]`` form of a state dict, in ManiSkill's key order."""
    from mani_skill.utils import common

    return common.flatten_state_dict(state, use_torch=True)


def unflatten_like(template: dict, flat: torch.Tensor) -> dict:
    """Split a flat state ``[B, D]`` into a dict shaped like ``template`` (ManiSkill's key order)."""
    out, start = {}, 0

    def walk(t: dict, o: dict):
        nonlocal start
        for key, value in t.items():
            if isinstance(value, dict):
                o[key] = {}
                walk(value, o[key])
                continue
            value = torch.as_tensor(value)
            width = 1 if value.ndim == 1 else value.shape[-1]
            o[key] = flat[:, start : start + width]
            if value.ndim == 1:
                o[key] = o[key][:, 0]
            start += width

    walk(template, out)
    if start != flat.shape[1]:
        raise ValueError(
            f"flat state has {flat.shape[1]} values but this env's state has {start}; "
            "it was made by another task or configuration. Prefer env.get_state_dict()."
        )
    return out


def scene_poses(state: dict) -> torch.Tensor:
    """``[B, D]`` floats: every actor's pose (position, wxyz quaternion) and every articulation's root pose and joint
    positions, from a ManiSkill state dict; velocities, controllers and drive targets left out."""
    parts = [v[:, :7] for v in state.get("actors", {}).values()]
    for v in state.get("articulations", {}).values():
        dof = (v.shape[1] - 13) // 2  # ManiSkill's articulation state: root pose (7), root velocities (6), qpos, qvel
        parts += [v[:, :7], v[:, 13 : 13 + dof]]
    if not parts:
        raise ValueError("the env's state holds no actor or articulation, so it has no poses to read")
    return torch.cat([torch.as_tensor(p).float() for p in parts], dim=1)
