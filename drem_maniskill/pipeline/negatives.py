"""Negatives files: scenes labelled with a depth no progress tree gives them, trained on beside the tree's nodes.

The policy rounds (``pipeline.policy_rounds``) write the states a policy reached that the reward over-pays; the scene
swap (``pipeline.scene_swap.swap_negatives``) writes the demo's robot ahead of its objects. Training adds them as
nodes (``pipeline.dataset.TreeDataset.add_negatives``). One HDF5 file, one row per negative:

    <camera>_rgb   uint8 [N, H, W, 3]   the model's cameras, as a tree holds them
    ft             float32 [N, 8, 6]    the wrist F/T history (zeros where the task has no sensor)
    poses          float32 [N, P]       the scene's poses, where the rows hold them
    depth          int64 [N]            the label: how far from the goal the triplet loss puts the row
    reward         float32 [N]          what the reward paid it when it was found (NaN for a scene swap)
    seed, step     int64 [N]            the episode and step it comes from (a scene swap: the robot's depth)

A row, as the writers hand it over: ``(inputs, reward, seed, step)`` with ``inputs`` the reward's model inputs of
one scene (``{camera: [1, H, W, 3], "ft": [1, 8, 6], "poses": [1, P]}``).
"""

from __future__ import annotations

from contextlib import contextmanager
from typing import Iterator, Sequence

import h5py
import numpy as np
import torch

from drem_maniskill.utils.atomic import atomic_path


def write_negatives(path, rows: list, depth, cameras: Sequence[str], has_ft: bool) -> None:
    """Write ``rows`` to the negatives file ``path`` atomically; ``depth``: one label for every row, or one per row."""
    with atomic_path(path) as tmp, h5py.File(tmp, "w") as f:
        for c in cameras:
            f.create_dataset(f"{c}_rgb", data=np.concatenate([x[c].numpy() for x, *_ in rows])
                             if rows else np.zeros((0, 1, 1, 3), np.uint8), compression="gzip")
        ft = [x["ft"].numpy() for x, *_ in rows] if has_ft else []
        f.create_dataset("ft", data=np.concatenate(ft) if ft else np.zeros((len(rows), 8, 6), np.float32))
        if rows and "poses" in rows[0][0]:
            f.create_dataset("poses", data=np.concatenate([x["poses"].numpy() for x, *_ in rows]))
        f.create_dataset("depth", data=np.broadcast_to(np.asarray(depth, np.int64), (len(rows),)))
        f.create_dataset("reward", data=np.array([r for _, r, _, _ in rows], np.float32))
        f.create_dataset("seed", data=np.array([s for _, _, s, _ in rows], np.int64))
        f.create_dataset("step", data=np.array([t for _, _, _, t in rows], np.int64))


@contextmanager
def open_negatives(path, cameras: Sequence[str]) -> Iterator[h5py.File]:
    """The negatives file ``path``, open for reading, once it is known to hold images of every camera in ``cameras``."""
    with h5py.File(path, "r") as f:
        missing = [c for c in cameras if f"{c}_rgb" not in f]
        if missing:
            raise ValueError(f"{path} has no {missing} images; it was collected for another model")
        yield f


@torch.no_grad()
def paid_on_negatives(reward, path, batch_size: int = 128) -> np.ndarray:
    """What ``reward`` (a ``DREMReward``) pays each row of the negatives file ``path`` ``[N]``."""
    with h5py.File(path, "r") as f:
        count = len(f["depth"])
        if not count:  # a round that found none writes no poses: there is nothing to pay
            return np.zeros(0, np.float32)
        batch = {m: torch.as_tensor(f[f"{m}_rgb"][()]) for m in reward.model.config.cameras}
        if reward.uses_ft:
            batch["ft"] = torch.as_tensor(f["ft"][()]).float()
        if reward.uses_poses:
            batch["poses"] = torch.as_tensor(f["poses"][()]).float()
    return torch.cat([reward({k: v[i:i + batch_size] for k, v in batch.items()})
                      for i in range(0, count, batch_size)]).numpy()
