"""Progress bars that also reach a log file: every long job's bar comes from ``progress_bar``.

tqdm's own ``disable=None`` hides a bar whenever stderr is not a terminal, so a job run with
``nohup ... > log 2>&1`` showed nothing for its whole length; and a bar left at tqdm's 0.1 s
refresh writes megabytes of carriage-return updates into such a log. Off a terminal the bar
is kept but refreshes every ``LOG_INTERVAL_S`` seconds.
"""

from __future__ import annotations

import sys

from tqdm import tqdm

# Seconds between a bar's updates when it writes to a file rather than a terminal.
LOG_INTERVAL_S = 30.0


def _is_terminal(stream) -> bool:
    isatty = getattr(stream, "isatty", None)
    try:
        return bool(isatty and isatty())
    except ValueError:  # a closed stream
        return False


def progress_bar(iterable=None, *, enabled: bool = True, **kwargs) -> tqdm:
    """A tqdm bar shown on a terminal and in a log file alike (refreshed every ``LOG_INTERVAL_S`` s off a terminal)."""
    stream = kwargs.get("file") or sys.stderr
    if not _is_terminal(stream):
        kwargs.setdefault("mininterval", LOG_INTERVAL_S)
        kwargs.setdefault("maxinterval", LOG_INTERVAL_S * 2)
    return tqdm(iterable, disable=not enabled, **kwargs)
