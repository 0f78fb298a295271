"""Calibrate ``drem.guard.SupportGuard``: the tree nodes' reconstruction errors per camera (not in the paper)."""

from __future__ import annotations

import numpy as np
import torch

from drem_maniskill.drem.guard import GUARD_QUANTILE, image_errors
from drem_maniskill.drem.reward import DREMReward
from drem_maniskill.pipeline.dataset import TreeDataset
from drem_maniskill.utils.atomic import write_json
from drem_maniskill.utils.progress import progress_bar


def calibrate_support(checkpoint: str, tree: str, out: str, quantile: float = GUARD_QUANTILE, batch: int = 256) -> dict:
    """Write ``out`` (JSON): ``tau``, the ``quantile`` of every tree node's reconstruction error per camera."""
    reward = DREMReward.from_checkpoint(checkpoint)
    data = TreeDataset(tree, reward.model.config)
    cams = list(reward.model.config.cameras)
    errors = {c: [] for c in cams}
    n = len(data.depth)
    for start in progress_bar(range(0, n, batch), desc="support: tree errors", unit="batch"):
        idx = torch.arange(start, min(start + batch, n))
        b = data.batch(idx)
        for c, e in image_errors(reward.model, b).items():
            errors[c].append(e.numpy())
    errors = {c: np.concatenate(v) for c, v in errors.items()}
    result = dict(
        checkpoint=str(checkpoint), tree=str(tree), nodes=n, quantile=quantile,
        tau={c: float(np.quantile(e, quantile)) for c, e in errors.items()},
        max={c: float(e.max()) for c, e in errors.items()},
        median={c: float(np.median(e)) for c, e in errors.items()},
    )
    write_json(out, result, indent=1)
    return result
