"""Atomic writes: a reader (or a resumed job) sees a file or folder whole, or its previous version, never a part.

Every file the package writes that another process or a later run reads goes through here: write into a temp
path beside the target (same folder, so the rename never crosses a file system), then rename over the target.

    with atomic_path("run/eval.csv") as tmp:
        write_csv(tmp)
    write_json("run/progress.json", {"steps": 100})
"""

from __future__ import annotations

import json
import os
import shutil
import tempfile
from contextlib import contextmanager
from pathlib import Path
from typing import Any, Iterator, Union

PathLike = Union[str, "os.PathLike[str]"]


@contextmanager
def atomic_path(path: PathLike, directory: bool = False) -> Iterator[Path]:
    """A fresh temp path beside ``path`` that replaces ``path`` when the block ends; removed if the block raises.

    ``directory``: the temp path is an empty folder, and it replaces a folder at ``path`` (an old one is removed
    first: a folder cannot be renamed over a non-empty one).
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    if directory:
        tmp = Path(tempfile.mkdtemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp"))
    else:
        fd, name = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
        os.close(fd)
        tmp = Path(name)
    try:
        yield tmp
        # mkstemp/mkdtemp make the path private; what the package writes is meant to be read by others.
        os.chmod(tmp, 0o755 if directory else 0o644)
        if directory and path.is_dir():
            shutil.rmtree(path)
        os.replace(tmp, path)
    finally:
        if tmp.is_dir():
            shutil.rmtree(tmp, ignore_errors=True)
        elif tmp.exists():
            tmp.unlink()


def write_text(path: PathLike, text: str) -> Path:
    """Write ``text`` to ``path`` atomically; returns the path."""
    with atomic_path(path) as tmp:
        tmp.write_text(text)
    return Path(path)


def write_json(path: PathLike, data: Any, indent: int = 2, **dumps_kwargs) -> Path:
    """Write ``data`` as JSON (with a final newline) to ``path`` atomically; returns the path."""
    return write_text(path, json.dumps(data, indent=indent, **dumps_kwargs) + "\n")


def copy_file(src: PathLike, dest: PathLike) -> Path:
    """Copy ``src`` to ``dest`` atomically; returns ``dest``."""
    with atomic_path(dest) as tmp:
        shutil.copyfile(src, tmp)
    return Path(dest)


def promote(partial: PathLike, final: PathLike) -> Path:
    """Rename a finished resume file (``<name>.partial``, grown in place over many runs) to its final name."""
    os.replace(partial, final)
    return Path(final)
