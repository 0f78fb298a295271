"""DREM's triplet loss on temporal positions (Section III-B.3 of the paper).

For a pair of states with temporal positions ``t1 <= t2`` (larger is closer to the goal) and
latent distances to the goal ``d1 = dist(h(s_t1), h(s_G))``, ``d2 = dist(h(s_t2), h(s_G))``,
the gap is ``g(s_t1, s_t2) = d1 - d2`` and

* non-neighbours (``t2 - t1 > eps``): ``max(0, beta1 (t2 - t1) - g(s_t1, s_t2))`` -- the later
  state must be closer to the goal by a margin growing with the time between them;
* neighbours (``0 <= t2 - t1 <= eps``): ``max(0, g(s_t2, s_t1)) + max(0, g(s_t1, s_t2) - beta2)``
  -- the later state must not be farther, and not closer by more than ``beta2``.

The total loss is ``L_triplet + alpha L_reconstruction`` with the paper's ``eps = 4``,
``beta1 = beta2 = 0.04``, ``alpha = 0.2``.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F


def triplet_loss(
    d1: torch.Tensor, d2: torch.Tensor, t1: torch.Tensor, t2: torch.Tensor,
    eps: float = 4.0, beta1: float = 0.04, beta2: float = 0.04,
) -> torch.Tensor:
    """Per-pair loss ``[B]`` from goal distances ``d1, d2`` of states at times ``t1, t2``.

    Pairs may come in either order; each is sorted so that ``t1 <= t2`` first.
    """
    swap = t1 > t2
    d1, d2 = torch.where(swap, d2, d1), torch.where(swap, d1, d2)
    t1, t2 = torch.where(swap, t2, t1), torch.where(swap, t1, t2)
    dt = (t2 - t1).to(d1.dtype)
    gap = d1 - d2  # g(s_t1, s_t2)
    far = torch.clamp(beta1 * dt - gap, min=0.0)
    near = torch.clamp(-gap, min=0.0) + torch.clamp(gap - beta2, min=0.0)
    return torch.where(dt > eps, far, near)


def reconstruction_loss(recon: dict, inputs: dict) -> torch.Tensor:
    """Sigmoid cross-entropy per image pixel plus L2 on the F/T history (Section III-B.2) and on the poses."""
    loss = recon[next(iter(recon))].new_zeros(())
    for key, pred in recon.items():
        if key in ("ft", "poses"):
            loss = loss + F.mse_loss(pred, inputs[key])
        else:
            loss = loss + F.binary_cross_entropy_with_logits(pred, inputs[key])
    return loss
