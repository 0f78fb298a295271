"""``drem-maniskill run-script SCRIPT.py -- ARGS``: run a ManiSkill script with our env ids registered.

ManiSkill's baselines and tools call ``gym.make(args.env_id)`` after importing only ManiSkill,
so our ids are unknown to them. The launcher imports ``drem_maniskill`` (registering
``PegInHole-v1``, ``USBInsertion-v1`` and the ``*-DREM-v1`` aliases) and then runs the script as
``__main__`` with ``sys.argv = [SCRIPT, *ARGS]``, exactly as ``python SCRIPT ARGS`` would;
``run-script -m MODULE -- ARGS`` does the same for ``python -m MODULE ARGS`` (ManiSkill's
benchmark runner ``mani_skill.examples.benchmarking.gpu_sim``).

Worker processes started with the ``forkserver`` context (ManiSkill's ``ppo_cpu.py``) get the
plugin too, through the fork server's preload list; under ``spawn`` workers, or without the
launcher, pass the id as ``drem_maniskill:PegInHole-DREM-v1`` (gymnasium imports the module in
every process that makes the env).
"""

from __future__ import annotations

import runpy
import sys
from pathlib import Path


def _register_everywhere() -> None:
    import multiprocessing

    import drem_maniskill.envs  # noqa: F401  (registers the ids before the script looks them up)

    # Vector envs in worker processes (ppo_cpu.py: AsyncVectorEnv with "forkserver") make their
    # envs in processes forked from the fork server, which imports these modules first.
    multiprocessing.set_forkserver_preload(["drem_maniskill"])


def run_script(script: str, args: list) -> None:
    """Run ``script`` as ``__main__`` with ``args`` after registering our envs."""
    path = Path(script)
    if not path.is_file():
        raise FileNotFoundError(f"script {script} not found")
    _register_everywhere()
    old_argv, old_path = sys.argv, list(sys.path)
    sys.argv = [str(path), *args]
    sys.path.insert(0, str(path.resolve().parent))  # as `python SCRIPT` puts the script's folder first
    try:
        runpy.run_path(str(path), run_name="__main__")
    finally:
        sys.argv, sys.path[:] = old_argv, old_path


def run_module(module: str, args: list) -> None:
    """Run ``module`` as ``python -m module args`` would, after registering our envs."""
    import importlib.util

    try:
        found = importlib.util.find_spec(module)
    except ImportError:  # a missing parent package raises instead of returning None
        found = None
    if found is None:
        raise FileNotFoundError(f"module {module} not found")
    _register_everywhere()
    old_argv = sys.argv
    sys.argv = [found.origin or module, *args]
    try:
        # alter_sys: the module sees itself as sys.modules["__main__"], as under `python -m`.
        runpy.run_module(module, run_name="__main__", alter_sys=True)
    finally:
        sys.argv = old_argv
