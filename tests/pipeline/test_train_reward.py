"""Reward training: exact resume after an interruption."""

from __future__ import annotations

import pytest
import torch

from drem_maniskill.drem.checkpoint import (
    load_checkpoint,
)
from drem_maniskill.pipeline.train_reward import TrainConfig, train_reward


@pytest.mark.slow
def test_training_resumes_exactly(pipeline, tmp_path):
    straight = train_reward(pipeline["tree"], str(tmp_path / "a"), TrainConfig.preset("tiny", iterations=12, save_every=6), progress=False)
    train_reward(pipeline["tree"], str(tmp_path / "b"), TrainConfig.preset("tiny", iterations=6, save_every=6), progress=False)
    resumed = train_reward(pipeline["tree"], str(tmp_path / "b"), TrainConfig.preset("tiny", iterations=12, save_every=6), progress=False)
    wa, wb = load_checkpoint(straight)[1], load_checkpoint(resumed)[1]
    for key in wa:
        torch.testing.assert_close(wa[key], wb[key], atol=1e-5, rtol=1e-4)
    assert (tmp_path / "a" / "tb").exists()
