"""Markdown tables of an examination's ``quality.json`` (and an image-only one beside it), for model cards and docs.

    .venv/bin/python scripts/quality_tables.py QUALITY_JSON [IMAGE_ONLY_QUALITY_JSON]
    (e.g. rewards/PegInHole-v1/quality.json rewards/PegInHole-v1/quality_image.json)
    .venv/bin/python scripts/quality_tables.py --check CHECK_REWARD_JSON
    (``check-reward``'s report, e.g. rewards/PegInHole-v1/check_reward.json)

Prints ``drem_maniskill.evaluate.targets.tables`` (the measures against their targets, the held positions, and with
a second file the two checkpoints side by side) or ``drem_maniskill.evaluate.check_reward.markdown_table``.
"""

from __future__ import annotations

import json
import sys


def main() -> None:
    """Command line."""
    if sys.argv[1:2] == ["--check"] and len(sys.argv) == 3:
        from drem_maniskill.evaluate.check_reward import markdown_table

        print(markdown_table(json.load(open(sys.argv[2]))))
        return
    from drem_maniskill.evaluate.targets import tables

    files = [json.load(open(p)) for p in sys.argv[1:3]]
    if not files:
        sys.exit(__doc__)
    print(tables(files[0], files[1] if len(files) > 1 else None))


if __name__ == "__main__":
    main()
