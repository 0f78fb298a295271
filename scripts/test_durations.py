"""Write ``tests/durations.json``, each test module's seconds, from a pytest run's ``--durations=0`` report.

The test session starts the slowest modules first (``tests/conftest.py``): with one xdist worker per core and a
module on one worker, a long module left for last would run alone at the end.

    make test PYTEST_ARGS="--durations=0" | tee test.log && .venv/bin/python scripts/test_durations.py test.log
"""

from __future__ import annotations

import json
import re
import sys
from pathlib import Path

LINE = re.compile(r"^([0-9.]+)s (?:call|setup|teardown)\s+(\S+?\.py)::")


def module_seconds(report: str) -> dict:
    """Each module's summed setup, call and teardown seconds in a ``--durations=0`` report."""
    seconds: dict = {}
    for line in report.splitlines():
        m = LINE.match(line)
        if m:
            seconds[m.group(2)] = seconds.get(m.group(2), 0.0) + float(m.group(1))
    return seconds


def main() -> None:
    """Read the report named on the command line and write the durations file."""
    if len(sys.argv) != 2:
        sys.exit(f"usage: {sys.argv[0]} <pytest output with --durations=0>")
    seconds = module_seconds(Path(sys.argv[1]).read_text())
    if not seconds:
        sys.exit(f"{sys.argv[1]} holds no durations: run pytest with --durations=0")
    out = Path(__file__).resolve().parents[1] / "tests" / "durations.json"
    out.write_text(json.dumps({k: round(v) for k, v in sorted(seconds.items(), key=lambda kv: -kv[1])},
                              indent=1) + "\n")
    print(f"{out}: {len(seconds)} modules, {sum(seconds.values()):.0f} s")


if __name__ == "__main__":
    main()
