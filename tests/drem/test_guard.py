"""The support guard on DREM's reward (not in the paper): weights, the wrapper, the calibration."""

from __future__ import annotations

import json

import gymnasium as gym
import numpy as np
import pytest
import torch

from drem_maniskill.drem.guard import SupportGuard, guard_weight, image_errors
from drem_maniskill.drem.reward import DREMReward
from tests.conftest import tiny_checkpoint


def test_guard_weight_is_one_inside_the_trees_errors_and_zero_at_twice_them():
    tau = {"fixed": 0.01, "wrist": 0.02}
    errors = {"fixed": torch.tensor([0.005, 0.01, 0.015, 0.02, 0.03, 0.005]),
              "wrist": torch.tensor([0.01, 0.01, 0.01, 0.01, 0.01, 0.03])}
    torch.testing.assert_close(guard_weight(errors, tau), torch.tensor([1.0, 1.0, 0.5, 0.0, 0.0, 0.5]))


def test_support_guard_scales_the_drem_reward_by_its_weight(tmp_path):
    ckpt = tiny_checkpoint(tmp_path / "tiny.pt", "PegInHole-v1")
    action = torch.tensor([[0.3, -0.2, -0.5, 0.0, 0.0, 0.1]])
    rewards = {}
    taus = [("plain", None), ("wide", {"fixed": 10.0, "wrist": 10.0}), ("tight", {"fixed": 1e-6, "wrist": 1e-6})]
    for name, tau in taus:
        env = gym.make("PegInHole-v1", obs_mode="state_dict", reward_mode="drem", drem_checkpoint=str(ckpt))
        env = env if tau is None else SupportGuard(env, tau)
        env.reset(seed=2)
        _, r, _, _, info = env.step(action)
        rewards[name] = float(r)
        if tau is not None:
            assert info["drem_support"].shape == (1,)
        env.close()
    assert rewards["plain"] != 0.0
    assert rewards["wide"] == pytest.approx(rewards["plain"], abs=1e-6)  # within the tree's errors: untouched
    assert rewards["tight"] == 0.0  # nothing reconstructs that well: no pay
    with pytest.raises(ValueError, match="no threshold for cameras"):
        SupportGuard(gym.make("PegInHole-v1", obs_mode="state_dict", reward_mode="drem", drem_checkpoint=str(ckpt)),
                     {"fixed": 1.0})


@pytest.mark.slow
def test_calibration_reads_every_tree_node(pipeline, tmp_path):
    from drem_maniskill.pipeline.dataset import TreeDataset
    from drem_maniskill.pipeline.support import calibrate_support

    out = tmp_path / "support.json"
    result = calibrate_support(pipeline["checkpoint"], pipeline["tree"], str(out), quantile=0.5)
    assert json.loads(out.read_text())["tau"] == result["tau"]
    reward = DREMReward.from_checkpoint(pipeline["checkpoint"])
    data = TreeDataset(pipeline["tree"], reward.model.config)
    assert result["nodes"] == len(data.depth)
    errors = image_errors(reward.model, data.batch(torch.arange(len(data.depth))))
    for c, e in errors.items():
        assert result["tau"][c] == pytest.approx(float(np.median(e.numpy())), rel=1e-4)
        assert result["max"][c] == pytest.approx(float(e.max()), rel=1e-4)
