"""State trees: flatten and unflatten in ManiSkill's order, one step of a recording, broadcast to n envs."""

from __future__ import annotations

import pytest
import torch

from drem_maniskill.utils.state import broadcast_state, first_leaf, flatten_state, state_at, unflatten_like


def _tree(b: int) -> dict:
    return {"actors": {"a": torch.arange(b * 3.0).reshape(b, 3)}, "flag": torch.arange(float(b)),
            "task": {"ft": torch.ones(b, 4)}}


def test_unflatten_inverts_flatten_in_maniskills_key_order():
    tree = _tree(2)
    flat = flatten_state(tree)
    assert flat.shape == (2, 3 + 1 + 4)
    back = unflatten_like(tree, flat)
    assert torch.equal(back["actors"]["a"], tree["actors"]["a"]) and torch.equal(back["flag"], tree["flag"])
    assert back["flag"].shape == (2,) and torch.equal(back["task"]["ft"], tree["task"]["ft"])


def test_unflatten_rejects_a_state_of_another_shape():
    with pytest.raises(ValueError, match="flat state has 9 values but this env's state has 8.*get_state_dict"):
        unflatten_like(_tree(1), torch.zeros(1, 9))


def test_one_step_broadcast_to_n_envs_are_independent_copies():
    recording = {"actors": {"a": torch.arange(12.0).reshape(4, 3)}, "flag": torch.arange(4.0)}
    step = state_at(recording, 2)
    assert torch.equal(step["actors"]["a"], torch.tensor([[6.0, 7.0, 8.0]])) and step["flag"].tolist() == [2.0]
    batch = broadcast_state(step, 3)
    assert batch["actors"]["a"].shape == (3, 3) and torch.equal(batch["actors"]["a"][2], torch.tensor([6.0, 7.0, 8.0]))
    batch["actors"]["a"][0, 0] = -1
    assert batch["actors"]["a"][1, 0] == 6.0 and step["actors"]["a"][0, 0] == 6.0
    assert first_leaf(recording) is recording["actors"]["a"]
