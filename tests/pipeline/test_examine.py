"""The examination's measures."""

import pytest


def test_pooled_spearman_uses_every_step_and_skips_constant_signals():
    from drem_maniskill.pipeline.examine import _pooled_spearman

    eps = [dict(rewards=[0.1, 0.2, 0.3], normalized_dense=[1.0, 2.0, 4.0]),
           dict(rewards=[0.5, 0.4], normalized_dense=[5.0, 4.5])]
    assert _pooled_spearman(eps, "normalized_dense") == pytest.approx(1.0)
    eps[1]["normalized_dense"] = [0.0, 9.0]  # one pair now runs against the rest
    assert _pooled_spearman(eps, "normalized_dense") < 1.0
    assert _pooled_spearman([dict(rewards=[1, 2, 3], insertion_depth=[0, 0, 0])], "insertion_depth") is None
    assert _pooled_spearman([dict(rewards=[1, 2, 3])], "insertion_depth") is None
