"""Negatives files: written with one depth label or one per row."""

import h5py
import numpy as np


def test_negatives_take_one_depth_label_or_one_per_row(tmp_path):
    import torch

    from drem_maniskill.pipeline.negatives import write_negatives

    rows = [({"fixed": torch.zeros(1, 8, 8, 3, dtype=torch.uint8)}, 0.5, 7, t) for t in range(3)]
    write_negatives(tmp_path / "one.h5", rows, 9, ["fixed"], False)
    write_negatives(tmp_path / "each.h5", rows, np.array([5, 6, 7]), ["fixed"], False)
    with h5py.File(tmp_path / "one.h5") as one, h5py.File(tmp_path / "each.h5") as each:
        assert one["depth"][()].tolist() == [9, 9, 9] and each["depth"][()].tolist() == [5, 6, 7]


def test_a_negatives_file_without_the_models_cameras_is_refused(tmp_path):
    import pytest
    import torch

    from drem_maniskill.pipeline.negatives import open_negatives, write_negatives

    rows = [({"fixed": torch.zeros(1, 8, 8, 3, dtype=torch.uint8)}, 0.5, 7, 0)]
    write_negatives(tmp_path / "n.h5", rows, 9, ["fixed"], False)
    with open_negatives(tmp_path / "n.h5", ["fixed"]) as f:
        assert f["fixed_rgb"].shape == (1, 8, 8, 3) and f["ft"].shape == (1, 8, 6)
    with pytest.raises(ValueError, match=r"has no \['wrist'\] images"):
        with open_negatives(tmp_path / "n.h5", ["fixed", "wrist"]):
            pass
