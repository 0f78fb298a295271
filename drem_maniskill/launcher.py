"""``drem-maniskill run-script SCRIPT.py -- ARGS``: run a ManiSkill script with our env ids registered.

ManiSkill's baselines and tools call ``gym.make(args.env_id)`` after importing only ManiSkill,
so our ids are unknown to them. The launcher imports ``drem_maniskill`` (registering
``PegInHole-v1``, ``USBInsertion-v1`` and the ``*-DREM-v1`` aliases) and then runs the script as
``__main__`` with ``sys.argv = [SCRIPT, *ARGS]``, exactly as ``python SCRIPT ARGS`` would.
Scripts that pass the id straight to ``gym.make`` also take ``drem_maniskill:PegInHole-DREM-v1``
without the launcher.
"""

from __future__ import annotations

import runpy
import sys
from pathlib import Path


def run_script(script: str, args: list) -> None:
    """Run ``script`` as ``__main__`` with ``args`` after registering our envs."""
    path = Path(script)
    if not path.is_file():
        raise FileNotFoundError(f"script {script} not found")
    import drem_maniskill  # noqa: F401  (registers the ids before the script looks them up)

    old_argv, old_path = sys.argv, list(sys.path)
    sys.argv = [str(path), *args]
    sys.path.insert(0, str(path.resolve().parent))  # as `python SCRIPT` puts the script's folder first
    try:
        runpy.run_path(str(path), run_name="__main__")
    finally:
        sys.argv, sys.path[:] = old_argv, old_path
