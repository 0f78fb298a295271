"""How every command line of the package ends: bad input is one ``<prog> <command>: error: ...`` line and exit 2."""

from __future__ import annotations

import os
import sys
from typing import Callable, Optional


def run_command(prog: str, args, check: Optional[Callable] = None) -> int:
    """Run ``check(args)`` then ``args.func(args)``; a ValueError or FileNotFoundError becomes an error line and 2.

    The messages of those errors name the problem and the fix, so a traceback would only hide
    them; ``DREM_DEBUG=1`` shows it anyway.
    """
    try:
        if check is not None:
            check(args)
        args.func(args)
    except (ValueError, FileNotFoundError) as err:
        if os.environ.get("DREM_DEBUG"):
            raise
        print(f"{prog} {args.command}: error: {err}", file=sys.stderr)
        return 2
    return 0
