"""The task progress tree as training data: what it holds, loaded into memory at the model's image size.

The file is the HDF5 that ``pipeline.tree.backward.backward_sample`` writes; ``pipeline.tree.tree_file`` reads it.
"""

from __future__ import annotations

import h5py
import numpy as np
import torch
import torch.nn.functional as F

from drem_maniskill.drem.model import CAMERA_OF, ModelConfig
from drem_maniskill.pipeline.negatives import open_negatives
from drem_maniskill.pipeline.tree import tree_file
from drem_maniskill.pipeline.tree.backward import ee_distance, median_step
from drem_maniskill.pipeline.tree.config import SamplerConfig


def dataset_modalities(path: str) -> tuple:
    """The modalities a progress tree holds: its cameras, and ``ft`` when the env had our sensor."""
    try:
        with tree_file.open_tree(path) as f:
            header = tree_file.read_header(f)
    except (OSError, ValueError):
        return ModelConfig().modalities  # TreeDataset reports what is wrong with the file
    ft = ("ft",) if header.get("has_ft", True) else ()
    if not header.get("config", {}).get("images", True):
        return ("poses",) + ft  # sampled without images
    cams = header.get("camera_map", dict(CAMERA_OF))
    return tuple(m for m in ("fixed", "wrist") if m in cams) + ft


def travel_labels(f, scale: float = 1.0) -> np.ndarray:
    """Temporal labels of an open tree's nodes: a seed at its depth, any other child at its seed's depth plus ``scale``
    labels per demo median step its random action carried the hand from the seed (``ee_distance``). The paper's depths
    give every child of a seed one label however far it moved; these keep the seeds' chain and put a child that
    wandered far beside its seed farther from the goal than one that stayed near it."""
    missing = [k for k in ("parent", "is_seed", "tcp_pose", "expert/tcp_pose") if k not in f]
    if missing:
        raise ValueError(f"{f.filename} holds no {missing}, which travel labels read; {tree_file.RESAMPLE}, or train "
                         "with travel_labels = 0")
    depth, parent = f["depth"][()].astype(np.float64), f["parent"][()]
    header = tree_file.read_header(f)
    rotation_weight = SamplerConfig.from_dict(header.get("config", {})).rotation_weight
    unit = median_step(f["expert/tcp_pose"][()].astype(np.float64), rotation_weight)
    if unit <= 0:
        raise ValueError(f"{f.filename}: the demo's hand never moves, so travel labels have no unit; train with "
                         "travel_labels = 0")
    tcp = f["tcp_pose"][()].astype(np.float64)
    child = ~f["is_seed"][()] & (parent >= 0)
    labels = depth.copy()
    labels[child] = depth[parent[child]] + scale * ee_distance(tcp[child], tcp[parent[child]], rotation_weight) / unit
    return labels


class TreeDataset:
    """The progress tree in memory: uint8 images at the model's size, F/T, scene poses (when read), depths, and the
    temporal labels the triplet loss reads (the depths, or with ``travel > 0`` ``travel_labels`` at that scale)."""

    def __init__(self, path: str, config: ModelConfig, travel: float = 0.0):
        self.travel = travel
        with tree_file.open_tree(path) as f:
            self.header = tree_file.read_header(f)
            try:  # every field, the ones the tree's header leaves out at their defaults
                self.header["config"] = SamplerConfig.from_dict(self.header.get("config", {})).to_dict()
            except (ValueError, TypeError) as err:
                raise ValueError(f"{path} records a sampler config this version cannot read ({err}); "
                                 f"{tree_file.RESAMPLE}") from err
            self.camera_map = self.header.get("camera_map", dict(CAMERA_OF))
            absent = [c for c in config.cameras if c not in self.camera_map or f"{c}_rgb" not in f]
            if absent and not self.header["config"].get("images", True):
                raise ValueError(f"{path} was sampled without images (sampler images = false), so a model reading "
                                 f"{list(config.cameras)} cannot train on it: train one that reads no camera "
                                 "(--modalities poses) or re-sample with images")
            if absent:
                raise ValueError(
                    f"{path} has no {absent} camera images ({self.header.get('env_id')} gives "
                    f"{sorted(self.camera_map)}); "
                    f"train with --modalities {' '.join(sorted(self.camera_map))}"
                    + (" ft" if self.header.get("has_ft", True) else "")
                )
            if "ft" in config.modalities and not self.header.get("has_ft", True):
                raise ValueError(
                    f"{path} was sampled on {self.header.get('env_id')}, which has no wrist F/T sensor; "
                    f"train with --modalities {' '.join(sorted(self.camera_map))}"
                )
            self.depth = torch.as_tensor(f["depth"][()]).long()
            self.label = self._labels(f)
            flags = f["in_start_region"][()]
            if not flags.any():
                raise ValueError(
                    f"{path} has no start-region states: the tree never reached the start region, so it cannot "
                    "define task progress from the start. Re-sample with a larger --max-depth."
                )
            self.images = {c: resize_images(f[f"{c}_rgb"], config.image_size) for c in config.cameras}
            self.ft = torch.as_tensor(f["ft"][()]).float()
            self.poses = None
            if "poses" in config.modalities:
                if "poses" not in f or "expert/first/poses" not in f:
                    raise ValueError(f"{path} holds no scene poses (it was sampled by an earlier version); "
                                     f"{tree_file.RESAMPLE} to train a model that reads poses")
                self.poses = torch.as_tensor(f["poses"][()]).float()
            # Raw camera images: h(s_0) and h(s_G) go through the same resizing as rewards do.
            self.expert = {
                which: {c: torch.as_tensor(f[f"expert/{which}/{c}_rgb"][()][None]) for c in config.cameras}
                | ({"ft": torch.as_tensor(f[f"expert/{which}/ft"][()][None]).float()}
                   if "ft" in config.modalities else {})
                | ({"poses": torch.as_tensor(f[f"expert/{which}/poses"][()][None]).float()}
                   if self.poses is not None else {})
                for which in ("first", "last")
            }
        self.goal_index = int(torch.nonzero(self.depth == 0)[0])
        self.tree_nodes = len(self.depth)
        self._index_depths()

    def _labels(self, f, tree: bool = True) -> torch.Tensor:
        """The temporal labels of an open tree's (or, ``tree`` False, negatives file's) nodes: travel labels for a tree
        when asked; a negative keeps the depth it was labelled."""
        if self.travel > 0 and tree:
            return torch.as_tensor(travel_labels(f, self.travel)).float()
        return torch.as_tensor(f["depth"][()]).float()

    def _index_depths(self) -> None:
        self.by_depth = {int(d): torch.nonzero(self.depth == d).flatten() for d in torch.unique(self.depth)}

    def add_trees(self, paths, config: ModelConfig) -> int:
        """Append the nodes of more progress trees (other demo episodes of the same env) at their depths; returns how
        many. The goal, ``h(s_0)`` and ``h(s_G)`` stay this tree's: every tree is taught toward one latent goal."""
        added = 0
        for path in paths:
            with tree_file.open_tree(path) as f:
                header = tree_file.read_header(f)
                if header.get("env_id") != self.header.get("env_id"):
                    raise ValueError(f"{path} was sampled on {header.get('env_id')}, the first tree on "
                                     f"{self.header.get('env_id')}; a forest's trees come from one task's demo")
                if header.get("camera_map", dict(CAMERA_OF)) != self.camera_map:
                    raise ValueError(f"{path} holds cameras {header.get('camera_map')}, the first tree "
                                     f"{self.camera_map}; sample every tree from the same demo file")
                added += self._append(f, config, tree=True)
        self.tree_nodes += added
        self._index_depths()
        return added

    def _append(self, f, config: ModelConfig, tree: bool, repeat: int = 1) -> int:
        """Append the nodes of an open tree (``tree``) or negatives file, each ``repeat`` times; returns how many."""
        depth = torch.as_tensor(f["depth"][()]).long()
        if len(depth) == 0:
            return 0

        def rows(x: torch.Tensor) -> torch.Tensor:
            return x.repeat(repeat, *([1] * (x.dim() - 1))) if repeat > 1 else x

        for c in self.images:
            self.images[c] = torch.cat([self.images[c], rows(resize_images(f[f"{c}_rgb"], config.image_size))])
        self.ft = torch.cat([self.ft, rows(torch.as_tensor(f["ft"][()]).float())])
        if self.poses is not None:
            if "poses" not in f:
                raise ValueError(f"{f.filename} holds no scene poses, which this model reads; re-sample or "
                                 "re-collect it with this version")
            self.poses = torch.cat([self.poses, rows(torch.as_tensor(f["poses"][()]).float())])
        self.depth = torch.cat([self.depth, rows(depth)])
        self.label = torch.cat([self.label, rows(self._labels(f, tree))])
        return len(depth) * repeat

    def add_negatives(self, paths, config: ModelConfig, repeat: int = 1) -> int:
        """Append the negatives files ``paths`` (``pipeline.negatives``) as nodes at their labelled depths, each
        ``repeat`` times (so that a few are sampled as often as many would be); returns how many nodes. Their cameras
        must be the tree's."""
        added = 0
        for path in paths:
            with open_negatives(path, list(self.images)) as f:
                added += self._append(f, config, tree=False, repeat=int(repeat))
        self._index_depths()
        return added

    def batch(self, idx: torch.Tensor) -> dict:
        """Raw model inputs of nodes ``idx``."""
        out = {c: self.images[c][idx] for c in self.images}
        out["ft"] = self.ft[idx]
        if self.poses is not None:
            out["poses"] = self.poses[idx]
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
        second = torch.stack([self.by_depth[int(d)][torch.randint(len(self.by_depth[int(d)]), (1,), generator=gen)][0]
                              for d in depths[choice]])
        return first, second


# Regions of the tip around the opening (socket frame, metres), for ``tree_report``; the opening itself is the task's
# (``tree_file.tree_geometry``).
NEAR_HEIGHT = 0.006  # above the opening: the expert's pre-insertion height
CENTRED = 0.002  # off the axis: "a millimetre or two"


def resize_images(images, size: int, chunk: int = 4096) -> torch.Tensor:
    """uint8 images ``[n, size, size, 3]``, area-averaged from ``images`` ``[n, h, w, 3]`` (an array or h5py dataset).

    Read and resized ``chunk`` images at a time: the float copy of a whole tree's camera (100,000 nodes at 128 px:
    20 GB) would not fit beside the rest, while the result at 64 px is a quarter of the uint8 source.
    """
    if images.shape[1] == size:
        return torch.as_tensor(images[()]).contiguous()
    out = torch.empty((len(images), size, size, images.shape[-1]), dtype=torch.uint8)
    for start in range(0, len(images), chunk):
        x = torch.as_tensor(images[start:start + chunk]).permute(0, 3, 1, 2).float()
        # Area averaging keeps thin features like the peg visible.
        y = F.interpolate(x, size=(size, size), mode="area")
        out[start:start + len(y)] = y.round().clamp(0, 255).to(torch.uint8).permute(0, 2, 3, 1)
    return out


def tree_report(path: str, contact_force: float = 3.0) -> dict:
    """Where the tree's nodes are around the opening, and at which depths (our tasks' trees; they hold
    ``tip_in_socket``).

    Regions: ``inserted`` (in the opening: the task's ``inserted_height`` below the top face, within its
    ``opening_radius`` of the axis), ``beside, below the top face`` (lower than that and farther out: beside the
    socket, down to the floor, where the outward phase puts nodes), ``above, centred`` (up to 6 mm above the face,
    within 2 mm of the axis), ``above, off-centre`` (the same height, 2 mm to the opening radius off), ``in contact,
    not inserted`` (wrist force over ``contact_force`` with the tip not below ``inserted_height``: pressed on the face
    or the rim), ``far`` (the rest). A tree resolves progress near the opening when these hold nodes at depths that
    grow with their distance from the goal. ``inserted["past_entry"]`` counts inserted nodes labelled deeper than the
    ``entry_depth``: states in the opening that the reward is taught are farther from the goal than the part's way in.
    """
    with h5py.File(path, "r") as f:
        if "tip_in_socket" not in f:
            return {}
        geometry = tree_file.tree_geometry(f)
        tip, depth = f["tip_in_socket"][()], f["depth"][()]
        force = np.abs(f["ft"][:, -1, 2])
        start = f.attrs.get("start_depth")  # None until the backward loop reached the start region
    radial, z = np.linalg.norm(tip[:, :2], axis=1), tip[:, 2]
    below = z < geometry.inserted_height
    inserted = geometry.in_opening(tip)
    contact = (force > contact_force) & ~below
    near = (z >= 0) & (z <= NEAR_HEIGHT)
    regions = {
        "inserted": inserted,
        "beside, below the top face": below & ~inserted,
        "above, centred": near & (radial <= CENTRED) & ~contact,
        "above, off-centre": near & (radial > CENTRED) & (radial <= geometry.opening_radius) & ~contact,
        "in contact, not inserted": contact,
    }
    regions["far"] = ~np.any(np.stack(list(regions.values())), axis=0)
    out = {}
    for name, mask in regions.items():
        d = depth[mask]
        out[name] = dict(nodes=int(mask.sum()), depth_mean=float(d.mean()) if len(d) else None,
                         depth_min=int(d.min()) if len(d) else None, depth_max=int(d.max()) if len(d) else None)
    if start is not None:
        entry = tree_file.face_entry_depth(path, int(start))
        # Labelled farther from the goal than the part's entry into the opening, yet in it: the backward loop's
        # own noise (children of the entry seed that went in), plus any lineage child kept in the opening.
        out["inserted"]["past_entry"] = int((inserted & (depth > entry)).sum())
        out["entry_depth"] = entry
    out["tree_depth"] = int(depth.max())
    return out
