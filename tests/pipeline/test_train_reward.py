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


@pytest.mark.slow
def test_a_slim_tree_trains_the_same_model_without_maniskill(pipeline, tmp_path):
    """scripts/slim_tree.py + scripts/train_reward_standalone.py: what a GPU box without ManiSkill runs."""
    import subprocess
    import sys
    from pathlib import Path

    import h5py

    root = Path(__file__).resolve().parents[2]
    slim = tmp_path / "slim.h5"
    subprocess.run([sys.executable, str(root / "scripts/slim_tree.py"), pipeline["tree"], str(slim), "--no-compression"],
                   check=True, capture_output=True)
    with h5py.File(slim, "r") as f:
        assert f["fixed_rgb"].shape[1:] == (64, 64, 3)
    straight = train_reward(pipeline["tree"], str(tmp_path / "a"), TrainConfig.preset("tiny", iterations=6), progress=False)
    # ManiSkill made unimportable: the package is entered without its __init__ (which registers the tasks).
    code = ("import runpy, sys; sys.modules['mani_skill'] = None; sys.argv = sys.argv[1:]; "
            "runpy.run_path(sys.argv[0], run_name='__main__'); "
            "assert not any(m.startswith(('mani_skill', 'sapien', 'gymnasium')) and sys.modules[m] for m in sys.modules)")
    subprocess.run([sys.executable, "-c", code, str(root / "scripts/train_reward_standalone.py"), "--dataset", str(slim),
                    "--out", str(tmp_path / "b"), "--preset", "tiny", "--iterations", "6", "--device", "cpu"],
                   check=True, capture_output=True)
    wa, wb = load_checkpoint(straight)[1], load_checkpoint(str(tmp_path / "b" / "drem.pt"))[1]
    for key in wa:
        torch.testing.assert_close(wa[key], wb[key], atol=1e-5, rtol=1e-4)
