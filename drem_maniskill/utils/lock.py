"""One process per output folder: an advisory lock file holding the holder's pid.

Two processes resuming the same folder (a killed job's orphaned worker and its rerun, or two commands pointed at one
``--out``) would each append to the same partial files; the second one waits for the first, then fails naming it.
"""

from __future__ import annotations

import fcntl
import os
import time
from contextlib import contextmanager
from pathlib import Path
from typing import Iterator


@contextmanager
def folder_lock(folder, wait_s: float, doing: str, resume_hint: str, who: str) -> Iterator[None]:
    """Hold ``folder/.lock``; another holder is waited for up to ``wait_s`` seconds, then a RuntimeError names it.

    ``doing``: what the holder does to the folder ("trained"); ``resume_hint``: how a rerun goes on; ``who``: the
    prefix of the waiting message ("train-policy").
    """
    path = Path(folder) / ".lock"
    path.parent.mkdir(parents=True, exist_ok=True)
    fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
    try:
        deadline, told = time.monotonic() + wait_s, False
        while True:
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
                break
            except BlockingIOError:
                holder = path.read_text().strip() or "unknown"
                if time.monotonic() >= deadline:
                    raise RuntimeError(
                        f"{folder} is being {doing} by another process (pid {holder}); stop that process or let "
                        f"it finish, then rerun: {resume_hint}") from None
                if not told:
                    print(f"[{who}] {folder} is being {doing} by pid {holder}; waiting up to {wait_s:.0f} s",
                          flush=True)
                    told = True
                time.sleep(0.25)
        os.ftruncate(fd, 0)
        os.pwrite(fd, str(os.getpid()).encode(), 0)
        yield
    finally:
        os.close(fd)  # closing the descriptor releases the lock, also when the process is killed
