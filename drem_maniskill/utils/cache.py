"""Small files the package generates at run time (lean URDF, convex meshes), written atomically."""

from __future__ import annotations

import hashlib
import os
import tempfile
from pathlib import Path

from drem_maniskill.utils.atomic import write_text


def cache_dir() -> Path:
    """The package's cache folder (``$XDG_CACHE_HOME/drem_maniskill``, else a temp folder)."""
    root = Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache")) / "drem_maniskill"
    try:
        root.mkdir(parents=True, exist_ok=True)
        return root
    except OSError:
        root = Path(tempfile.gettempdir()) / "drem_maniskill"
        root.mkdir(parents=True, exist_ok=True)
        return root


def cached_text_file(stem: str, suffix: str, text: str) -> str:
    """Path of a cache file holding ``text``; written once, named by the content's hash."""
    folder = cache_dir()
    path = folder / f"{stem}_{hashlib.sha256(text.encode()).hexdigest()[:12]}{suffix}"
    if not path.exists():
        # Several worker processes may create the same file at once: each writes whole, the last one wins.
        write_text(path, text)
    return str(path)
