"""The progress tree as training data: what it refuses."""

from __future__ import annotations

import h5py
import pytest

from drem_maniskill.pipeline.train_reward import TrainConfig, train_reward


@pytest.mark.slow
def test_dataset_without_start_region_is_rejected(pipeline, tmp_path):
    bad = tmp_path / "bad.h5"
    bad.write_bytes(open(pipeline["tree"], "rb").read())
    with h5py.File(bad, "a") as f:
        f["in_start_region"][...] = False
    with pytest.raises(ValueError, match="no start-region states"):
        train_reward(str(bad), str(tmp_path / "r"), TrainConfig.preset("tiny"), progress=False)
