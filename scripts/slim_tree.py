"""Copy a progress tree with its images already at the model's size, to carry it to a GPU machine.

    .venv/bin/python scripts/slim_tree.py TREE.h5 OUT.h5 [--image-size 64]

``TreeDataset`` area-averages the 128 px renders to the model's size when it loads a tree; this
writes exactly those images (the same ``TreeDataset._resize``), so training on the copy is
training on the tree. The expert's first and last observations stay at full size, as the
reward's anchors ``h(s_0)`` and ``h(s_G)`` go through the reward's own resizing. A 64 px copy of
a 14,000-node tree is about a quarter of the original's size.
"""

from __future__ import annotations

import argparse

import h5py

from drem_maniskill.pipeline.dataset import TreeDataset

IMAGE_KEYS = ("fixed_rgb", "wrist_rgb")


def slim_tree(src: str, dst: str, image_size: int = 64, chunk: int = 2048, compression: str | None = "gzip") -> str:
    """Write ``dst``: ``src`` with its node images at ``image_size`` px; returns ``dst``."""
    with h5py.File(src, "r") as f, h5py.File(dst + ".tmp", "w") as g:
        if not f.attrs.get("complete", False):
            raise ValueError(f"{src} is an unfinished sampling run; finish it with `drem-maniskill sample` first")
        for key, value in f.attrs.items():
            g.attrs[key] = value
        for key in f:
            if key in IMAGE_KEYS:
                n = f[key].shape[0]
                out = g.create_dataset(key, (n, image_size, image_size, 3), "uint8", chunks=(64, image_size, image_size, 3),
                                       compression=compression)
                for i in range(0, n, chunk):
                    out[i : i + chunk] = TreeDataset._resize(f[key][i : i + chunk], image_size).numpy()
            else:
                f.copy(f[key], g, name=key)
    import os

    os.replace(dst + ".tmp", dst)
    return dst


def main() -> None:
    """Command line."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("tree")
    parser.add_argument("out")
    parser.add_argument("--image-size", type=int, default=64)
    parser.add_argument("--no-compression", action="store_true",
                        help="store the images raw (for an outer compressor such as xz, which packs them tighter)")
    args = parser.parse_args()
    print(slim_tree(args.tree, args.out, args.image_size, compression=None if args.no_compression else "gzip"))


if __name__ == "__main__":
    main()
