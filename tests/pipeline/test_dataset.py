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


def test_tree_report_places_nodes_around_the_opening(tmp_path):
    """Regions from the tip position and the wrist force, with the depths of their nodes."""
    import h5py
    import numpy as np

    from drem_maniskill.pipeline.dataset import tree_report

    tip = np.array([[0, 0, -0.02], [0, 0, -0.005], [0.001, 0, 0.004], [0.005, 0, 0.003], [0.004, 0, 0.0], [0.05, 0, 0.05],
                    [0.06, 0.02, -0.045]])
    force = np.array([0.0, 2.0, 0.0, 0.0, 8.0, 0.0, 20.0])
    ft = np.zeros((len(tip), 8, 6), np.float32)
    ft[:, -1, 2] = -force
    with h5py.File(tmp_path / "tree.h5", "w") as f:
        f["tip_in_socket"], f["depth"], f["ft"] = tip, np.array([0, 1, 3, 4, 4, 9, 12]), ft
    report = tree_report(str(tmp_path / "tree.h5"))
    assert report["inserted"] == dict(nodes=2, depth_mean=0.5, depth_min=0, depth_max=1)
    assert report["above, centred"]["nodes"] == 1 and report["above, centred"]["depth_min"] == 3
    assert report["above, off-centre"]["nodes"] == 1 and report["in contact, not inserted"]["depth_max"] == 4
    # Pressed on the floor beside the socket: neither inserted nor contact at the opening.
    assert report["beside, below the top face"] == dict(nodes=1, depth_mean=12.0, depth_min=12, depth_max=12)
    assert report["far"]["nodes"] == 1 and report["tree_depth"] == 12
    with h5py.File(tmp_path / "stock.h5", "w") as f:
        f["depth"] = np.zeros(1)
    assert tree_report(str(tmp_path / "stock.h5")) == {}
