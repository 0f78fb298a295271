"""The task progress tree's HDF5 file: the one module that writes and reads its layout.

One row per node in each of ``DATASET_KEYS`` (images, F/T, the scene's poses, the end-effector pose, the node's
``depth`` label and ``parent``), and:

* ``attrs["header"]``: JSON of the sampler config (``SamplerConfig.to_dict()``), the env, its cameras and, on our
  insertion tasks, its ``socket_geometry``;
* ``expert/{first,last}/...``: the expert's first and last observations (the reward's anchors), ``expert/tcp_pose``;
* ``seeds/<group>/{state,in_start_region,node}``: the seeds each depth or phase step kept, with their flat states;
* counters in ``attrs``: ``node_count``, ``completed_depth``, ``start_depth``, one per extra phase
  (``<phase>_completed``), ``complete`` and ``final_depth`` once finished.

Sampling writes ``<out>.partial`` depth by depth; every counter is written after the rows it counts, so an interrupted
run resumes from the last complete step (``truncate`` cuts the rows past ``node_count``), and the finished file is
renamed to ``<out>``.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Optional

import h5py
import numpy as np

from drem_maniskill.envs.adapter import SocketGeometry, socket_geometry_of
from drem_maniskill.utils.atomic import promote

DATASET_KEYS = ("fixed_rgb", "wrist_rgb", "ft", "poses", "tcp_pose", "colors", "placement", "tip_in_socket", "depth",
                "parent", "in_start_region", "is_seed")
RESAMPLE = "re-sample it with `drem-maniskill sample`"


def partial_path(out_path) -> Path:
    """Where a sampling run writes the tree ``out_path`` until it is complete."""
    out_path = Path(out_path)
    return out_path.with_name(out_path.name + ".partial")


def read_header(f: h5py.File) -> dict:
    """The header of an open tree file."""
    return json.loads(f.attrs["header"])


def open_tree(path) -> h5py.File:
    """A complete tree file, open for reading, or an error that says which command makes or finishes it."""
    if not Path(path).exists():
        raise FileNotFoundError(f"progress-tree dataset {path} not found; make one with `drem-maniskill sample`")
    try:
        f = h5py.File(path, "r")
    except OSError as err:
        raise ValueError(f"cannot read dataset {path}: {err}; it may be truncated, {RESAMPLE}") from err
    if not f.attrs.get("complete", False):
        f.close()
        raise ValueError(f"{path} is an unfinished sampling run; resume it with `drem-maniskill sample`")
    if "header" not in f.attrs or "depth" not in f:
        f.close()
        raise ValueError(f"{path} is not a progress tree (no header or depths); {RESAMPLE}")
    return f


def create(partial: Path, header: dict, first_obs: dict, last_obs: dict, expert_ee: np.ndarray, root: dict) -> list:
    """A new tree file: its header, the expert's anchors and end-effector path, the root (depth 0, its own seed)."""
    with h5py.File(partial, "w") as f:
        f.attrs["header"] = json.dumps(header)
        e = f.create_group("expert")
        for key, value in first_obs.items():
            e.create_dataset(f"first/{key}", data=value)
        for key, value in last_obs.items():
            e.create_dataset(f"last/{key}", data=value)
        e.create_dataset("tcp_pose", data=expert_ee[:, :7].astype(np.float32))
        e.create_dataset("ee_state", data=expert_ee.astype(np.float32))
    return append_depth(partial, root, 0, np.array([0]))


def set_header(path: Path, header: dict) -> None:
    """Replace the header (a resumed run's settings are its own from then on)."""
    with h5py.File(path, "a") as f:
        f.attrs["header"] = json.dumps(header)


def append_depth(path: Path, data: dict, depth, chosen: np.ndarray, group: Optional[str] = None,
                 counter: str = "completed_depth", count: Optional[int] = None, attrs: Optional[dict] = None) -> list:
    """Append one step's nodes and its chosen seeds in one go; returns the seeds' node indices.

    ``depth``: the nodes' label, or one per node. The seeds go to ``seeds/<group>`` (default ``depth_<depth>``), with
    ``attrs`` on the group. ``counter`` (default ``completed_depth``; each extra phase has its own) is set to ``count``
    (default ``depth``) and ``node_count`` grows, both last, so a run interrupted half-way through a step resumes from
    the previous one.
    """
    n = len(data["tcp_pose"])
    is_seed = np.zeros(n, bool)
    is_seed[chosen] = True
    rows = {k: data[k].astype(np.uint8) for k in ("fixed_rgb", "wrist_rgb") if k in data}
    rows.update({k: data[k].astype(np.float32) for k in ("colors", "placement", "tip_in_socket", "poses")
                 if k in data})
    rows.update(
        ft=data["ft"].astype(np.float32), tcp_pose=data["tcp_pose"].astype(np.float32),
        depth=np.broadcast_to(np.asarray(depth, np.int32), (n,)).copy(), parent=data["parent"].astype(np.int64),
        in_start_region=data["in_start_region"].astype(bool), is_seed=is_seed,
    )
    with h5py.File(path, "a") as f:
        first = int(f.attrs.get("node_count", 0))
        for key, value in rows.items():
            if key not in f and first > 0:
                continue  # a tree begun by a version that did not write this key: it goes on without it
            if key not in f:
                f.create_dataset(key, data=value, maxshape=(None, *value.shape[1:]),
                                 chunks=(min(64, max(n, 1)), *value.shape[1:]),
                                 compression="gzip" if value.dtype == np.uint8 else None)
            else:
                f[key].resize(first + n, axis=0)
                f[key][first:] = value
        nodes = [first + int(i) for i in chosen]
        g = f.require_group(f"seeds/{group or f'depth_{depth}'}")
        for key in list(g.keys()):
            del g[key]
        g.create_dataset("state", data=data["state"][chosen])
        g.create_dataset("in_start_region", data=data["in_start_region"][chosen].astype(bool))
        g.create_dataset("node", data=np.array(nodes, np.int64))
        g.attrs.update(attrs or {})
        f.attrs["node_count"] = first + n
        f.attrs[counter] = depth if count is None else count
    return nodes


def truncate(path: Path) -> None:
    """Cut the rows an interrupted step wrote past ``node_count``."""
    with h5py.File(path, "a") as f:
        count = int(f.attrs["node_count"])
        for key in DATASET_KEYS:
            if key in f and f[key].shape[0] > count:
                f[key].resize(count, axis=0)


def seeds_at(data, rows) -> list:
    """The seeds at ``rows`` of ``data`` (a step's merged children, or a ``seeds/`` group), as samplers take them."""
    return [dict(state=data["state"][i], in_start_region=data["in_start_region"][i]) for i in rows]


def read_seeds(group) -> tuple:
    """The seeds of an open ``seeds/<name>`` group, as the samplers take them, and their node indices."""
    seeds = [dict(state=s, in_start_region=r) for s, r in zip(group["state"][()], group["in_start_region"][()])]
    return seeds, [int(n) for n in group["node"][()]]


def completed(path: Path, counter: str) -> int:
    """The value of a completion counter (0 before its first step)."""
    with h5py.File(path, "r") as f:
        return int(f.attrs.get(counter, 0))


def start_depth(path: Path) -> Optional[int]:
    """The depth at which the backward loop reached the start region, once it has (else None)."""
    with h5py.File(path, "r") as f:
        value = f.attrs.get("start_depth")
    return None if value is None else int(value)


def mark_start_depth(path: Path, depth: int) -> int:
    """Record (once) the depth that reached the start region; returns it."""
    known = start_depth(path)
    if known is not None:
        return known
    with h5py.File(path, "a") as f:
        f.attrs["start_depth"] = depth
    return depth


def finish(partial: Path, out_path: Path) -> str:
    """Mark the tree complete (``final_depth``: the last depth of the backward and outward steps) and rename it."""
    with h5py.File(partial, "a") as f:
        f.attrs["complete"] = True
        f.attrs["final_depth"] = int(f.attrs["completed_depth"])
    return str(promote(partial, out_path))


def tree_geometry(f: h5py.File) -> SocketGeometry:
    """The socket geometry of an open tree: its header's, else its task's (trees that predate the header field)."""
    header = read_header(f) if "header" in f.attrs else {}
    if header.get("socket_geometry"):
        return SocketGeometry(**header["socket_geometry"])
    geometry = socket_geometry_of(header.get("env_id", ""))
    if geometry is None:
        raise ValueError(f"{f.filename} records no socket geometry and its env {header.get('env_id')!r} is not one of "
                         "our insertion tasks: it holds no opening to measure from")
    return geometry


def face_entry_depth(path, start: int) -> int:
    """The first backward depth whose seed's tip is out of the opening (above ``inserted_height``): where the part
    enters."""
    with h5py.File(path, "r") as f:
        if "tip_in_socket" not in f:
            raise ValueError(f"{path} holds no tip_in_socket: the face phase (--face-depth) needs one of our "
                             "insertion tasks")
        height = tree_geometry(f).inserted_height
        for depth in range(start + 1):
            node = int(f[f"seeds/depth_{depth}/node"][0])
            if f["tip_in_socket"][node][2] > height:
                return depth
    raise ValueError(f"no seed of {path} up to the start region is out of the opening; is the expert's goal inserted?")
