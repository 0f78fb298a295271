"""DREM's triplet loss (Section III-B.3)."""

import pytest
import torch

from drem_maniskill.pipeline.losses import triplet_loss


def t(*values):
    return torch.tensor(values, dtype=torch.float32)


def test_non_neighbours_need_a_margin_growing_with_time():
    # t2 - t1 = 10 > eps: margin 0.04 * 10 = 0.4; gap = 0.9 - 0.6 = 0.3 -> loss 0.1.
    assert triplet_loss(t(0.9), t(0.6), t(0), t(10)).item() == pytest.approx(0.1)
    # gap 0.5 >= 0.4: satisfied.
    assert triplet_loss(t(0.9), t(0.4), t(0), t(10)).item() == 0.0
    # Wrong order (later state farther): gap -0.2 -> 0.4 + 0.2.
    assert triplet_loss(t(0.4), t(0.6), t(0), t(10)).item() == pytest.approx(0.6)


def test_neighbours_must_be_close_but_not_too_close():
    # dt = 3 <= eps. gap = 0.02 in [0, beta2]: no loss.
    assert triplet_loss(t(0.52), t(0.50), t(5), t(8)).item() == 0.0
    # gap = 0.10 > beta2: 0.10 - 0.04.
    assert triplet_loss(t(0.60), t(0.50), t(5), t(8)).item() == pytest.approx(0.06)
    # gap = -0.05 (later farther): max(0, g(s_t2, s_t1)) = 0.05.
    assert triplet_loss(t(0.45), t(0.50), t(5), t(8)).item() == pytest.approx(0.05)


def test_boundary_dt_equal_eps_is_a_neighbour_pair():
    # dt = 4 = eps counts as neighbours (gap 0.1 -> 0.1 - beta2); dt = 5 is far (0.2 - 0.1).
    near = triplet_loss(t(0.6), t(0.5), t(0), t(4)).item()
    far = triplet_loss(t(0.6), t(0.5), t(0), t(5)).item()
    assert near == pytest.approx(0.1 - 0.04)
    assert far == pytest.approx(0.04 * 5 - 0.1)


def test_pair_order_does_not_matter_and_batches():
    d1, d2, t1, t2 = t(0.9, 0.45), t(0.6, 0.50), t(0, 5), t(10, 8)
    forward = triplet_loss(d1, d2, t1, t2)
    backward = triplet_loss(d2, d1, t2, t1)
    torch.testing.assert_close(forward, backward)
    torch.testing.assert_close(forward, t(0.1, 0.05))


def test_custom_hyper_parameters():
    assert triplet_loss(t(0.9), t(0.6), t(0), t(10), eps=20.0, beta2=0.5).item() == 0.0
    assert triplet_loss(t(0.9), t(0.6), t(0), t(10), beta1=0.1).item() == pytest.approx(0.7)
