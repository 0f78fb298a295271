"""The task progress tree as training data: what it holds, loaded into memory at the model's image size.

The file is the HDF5 that ``pipeline.sampling.backward_sample`` writes (``DATASET_KEYS``).
"""

from __future__ import annotations

import json
from pathlib import Path

import h5py
import numpy as np
import torch
import torch.nn.functional as F

from drem_maniskill.drem.model import CAMERA_OF, ModelConfig


def dataset_modalities(path: str) -> tuple:
    """The modalities a progress tree holds: its cameras, and ``ft`` when the env had our sensor."""
    try:
        with h5py.File(path, "r") as f:
            header = json.loads(f.attrs["header"])
    except (OSError, KeyError):
        return ModelConfig().modalities  # TreeDataset reports what is wrong with the file
    cams = header.get("camera_map", dict(CAMERA_OF))
    return tuple(m for m in ("fixed", "wrist") if m in cams) + (("ft",) if header.get("has_ft", True) else ())


class TreeDataset:
    """The progress tree in memory: uint8 images at the model's size, F/T, depths."""

    def __init__(self, path: str, config: ModelConfig):
        if not Path(path).exists():
            raise FileNotFoundError(f"progress-tree dataset {path} not found; make one with `drem-maniskill sample`")
        try:
            f = h5py.File(path, "r")
        except OSError as err:
            raise ValueError(f"cannot read dataset {path}: {err}; it may be truncated, re-run `drem-maniskill sample`") from err
        with f:
            if not f.attrs.get("complete", False):
                raise ValueError(f"{path} is an unfinished sampling run; resume it with `drem-maniskill sample`")
            self.header = json.loads(f.attrs["header"])
            self.camera_map = self.header.get("camera_map", dict(CAMERA_OF))
            absent = [c for c in config.cameras if c not in self.camera_map or f"{c}_rgb" not in f]
            if absent:
                raise ValueError(
                    f"{path} has no {absent} camera images ({self.header.get('env_id')} gives {sorted(self.camera_map)}); "
                    f"train with --modalities {' '.join(sorted(self.camera_map))}"
                    + (" ft" if self.header.get("has_ft", True) else "")
                )
            if "ft" in config.modalities and not self.header.get("has_ft", True):
                raise ValueError(
                    f"{path} was sampled on {self.header.get('env_id')}, which has no wrist F/T sensor; "
                    f"train with --modalities {' '.join(sorted(self.camera_map))}"
                )
            self.depth = torch.as_tensor(f["depth"][()]).long()
            flags = f["in_start_region"][()]
            if not flags.any():
                raise ValueError(
                    f"{path} has no start-region states: the tree never reached the start region, so it cannot "
                    "define task progress from the start. Re-sample with a larger --max-depth."
                )
            self.images = {c: self._resize(f[f"{c}_rgb"][()], config.image_size) for c in config.cameras}
            self.ft = torch.as_tensor(f["ft"][()]).float()
            # Raw camera images: h(s_0) and h(s_G) go through the same resizing as rewards do.
            self.expert = {
                which: {c: torch.as_tensor(f[f"expert/{which}/{c}_rgb"][()][None]) for c in config.cameras}
                | ({"ft": torch.as_tensor(f[f"expert/{which}/ft"][()][None]).float()} if "ft" in config.modalities else {})
                for which in ("first", "last")
            }
        self.goal_index = int(torch.nonzero(self.depth == 0)[0])
        self.by_depth = {int(d): torch.nonzero(self.depth == d).flatten() for d in torch.unique(self.depth)}

    @staticmethod
    def _resize(images: np.ndarray, size: int) -> torch.Tensor:
        x = torch.as_tensor(images)
        if x.shape[1] == size:
            return x.contiguous()
        # Once, at load time: area averaging keeps thin features like the peg visible.
        y = F.interpolate(x.permute(0, 3, 1, 2).float(), size=(size, size), mode="area")
        return y.round().clamp(0, 255).to(torch.uint8).permute(0, 2, 3, 1).contiguous()

    def batch(self, idx: torch.Tensor) -> dict:
        """Raw model inputs of nodes ``idx``."""
        out = {c: self.images[c][idx] for c in self.images}
        out["ft"] = self.ft[idx]
        return out

    def sample_pairs(self, n: int, eps: float, gen: torch.Generator) -> tuple[torch.Tensor, torch.Tensor]:
        """``n`` pairs of node indices: the first half neighbours (|depth gap| <= eps), the rest not."""
        depths = torch.tensor(sorted(self.by_depth))
        first = torch.randint(len(self.depth), (n,), generator=gen)
        d1 = self.depth[first]
        gaps = (depths[None, :] - d1[:, None]).abs()
        near = gaps <= eps
        want_near = torch.arange(n) < n // 2
        allowed = torch.where(want_near[:, None], near, ~near)
        # A node with no far depth (tiny trees) falls back to a neighbour rather than failing.
        allowed = torch.where(allowed.any(1, keepdim=True), allowed, near)
        choice = torch.multinomial(allowed.float(), 1, generator=gen).flatten()
        second = torch.stack([self.by_depth[int(d)][torch.randint(len(self.by_depth[int(d)]), (1,), generator=gen)][0] for d in depths[choice]])
        return first, second


# Regions of the tip around the opening (socket frame, metres), for ``tree_report``.
NEAR_HEIGHT = 0.006  # above the opening: the expert's pre-insertion height
CENTRED = 0.002  # off the axis: "a millimetre or two"
INSERTED_HEIGHT = -0.001  # m: a tip lower than this below the top face is in the opening or beside the socket;
# a backward seed's tip above it is out of the opening (``face_entry_depth``)
OPENING_RADIUS = 0.01  # m off the axis: lower than INSERTED_HEIGHT and this close, the tip is in the opening
# (both tasks' blocks are solid farther out: the USB port's housing reaches 8.75 mm, the plug's shell 2.25 mm more)


def in_opening(tip: np.ndarray) -> np.ndarray:
    """Rows of ``tip_in_socket`` ``[n, 3]`` whose tip is in the opening: below ``INSERTED_HEIGHT``, within ``OPENING_RADIUS``."""
    tip = np.asarray(tip)
    return (tip[:, 2] < INSERTED_HEIGHT) & (np.linalg.norm(tip[:, :2], axis=1) <= OPENING_RADIUS)


def tree_report(path: str, contact_force: float = 3.0) -> dict:
    """Where the tree's nodes are around the opening, and at which depths (our tasks' trees; they hold ``tip_in_socket``).

    Regions: ``inserted`` (tip more than 1 mm below the top face, within 1 cm of the axis),
    ``beside, below the top face`` (lower than that and farther out: beside the socket, down to the
    floor, where ``SamplerConfig.outward_depth`` puts nodes), ``above, centred`` (up to 6 mm above
    the face, within 2 mm of the axis), ``above, off-centre`` (the same height, 2-10 mm off),
    ``in contact, not inserted`` (wrist force over ``contact_force`` with the tip not below 1 mm:
    pressed on the face or the rim), ``far`` (the rest). A tree resolves progress near the
    opening when these hold nodes at depths that grow with their distance from the goal.
    ``inserted["past_entry"]`` counts inserted nodes labelled deeper than the ``entry_depth``: states in the
    opening that the reward is taught are farther from the goal than the part's way in.
    """
    with h5py.File(path, "r") as f:
        if "tip_in_socket" not in f:
            return {}
        tip, depth = f["tip_in_socket"][()], f["depth"][()]
        force = np.abs(f["ft"][:, -1, 2])
        start = f.attrs.get("start_depth")  # None until the backward phase reached the start region
    radial, z = np.linalg.norm(tip[:, :2], axis=1), tip[:, 2]
    below = z < INSERTED_HEIGHT
    inserted = in_opening(tip)
    beside = below & ~inserted
    contact = (force > contact_force) & ~below
    near = (z >= 0) & (z <= NEAR_HEIGHT)
    regions = {
        "inserted": inserted,
        "beside, below the top face": beside,
        "above, centred": near & (radial <= CENTRED) & ~contact,
        "above, off-centre": near & (radial > CENTRED) & (radial <= 0.01) & ~contact,
        "in contact, not inserted": contact,
    }
    regions["far"] = ~np.any(np.stack(list(regions.values())), axis=0)
    out = {}
    for name, mask in regions.items():
        d = depth[mask]
        out[name] = dict(nodes=int(mask.sum()), depth_mean=float(d.mean()) if len(d) else None,
                         depth_min=int(d.min()) if len(d) else None, depth_max=int(d.max()) if len(d) else None)
    if start is not None:
        entry = face_entry_depth(path, int(start))
        # Labelled farther from the goal than the part's entry into the opening, yet in it: the backward phase's
        # own noise (children of the entry seed that went in), plus any lineage child kept in the opening.
        out["inserted"]["past_entry"] = int((inserted & (depth > entry)).sum())
        out["entry_depth"] = entry
    out["tree_depth"] = int(depth.max())
    return out


def face_entry_depth(path, start_depth: int) -> int:
    """The first backward depth whose seed's tip is out of the opening (``INSERTED_HEIGHT``): where the part enters."""
    with h5py.File(path, "r") as f:
        if "tip_in_socket" not in f:
            raise ValueError(f"{path} holds no tip_in_socket: the face phase (--face-depth) needs one of our insertion tasks")
        for depth in range(start_depth + 1):
            node = int(f[f"seeds/depth_{depth}/node"][0])
            if f["tip_in_socket"][node][2] > INSERTED_HEIGHT:
                return depth
    raise ValueError(f"no seed of {path} up to the start region is out of the opening; is the expert's goal inserted?")
