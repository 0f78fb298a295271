"""The source stays readable: short files and functions, ruff clean, no development history in the text.

A file in ``drem_maniskill/`` is at most 500 lines and a function or method at most 80 (def line
to last line); ``ruff check`` (the ``[tool.ruff]`` settings of pyproject.toml) passes on the
repository; and the code, tests, scripts, tasks, rewards and docs name things by what they are,
never by when they were made: no progress-report numbers, issue numbers or checkpoint code names.
"""

from __future__ import annotations

import ast
import importlib.util
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "drem_maniskill"

MAX_FILE_LINES = 500
MAX_FUNCTION_LINES = 80

# Progress-report numbers, issue numbers and the checkpoint code names. The names are written with
# brackets so that this file does not match its own pattern.
# A code name may sit inside a JSON key (``last_20_<name>``), so "_" counts as a boundary too.
HISTORY = r"\b[Ss]tops? [0-9]+|\b[Ii]ssues? [0-9]+|(^|[^A-Za-z0-9])(G[T]|G[F]|G[2])([^A-Za-z0-9]|$)"
HISTORY_PATHS = ["drem_maniskill/", "tests/", "scripts/", "tasks/", "rewards/", "docs/", "README.md", "bench/",
                 "experiments/", "CHANGELOG.md", "Makefile", "pyproject.toml", ".ci/"]


def _sources() -> list:
    return sorted(PACKAGE.rglob("*.py"))


def test_no_package_file_is_over_500_lines():
    long = {}
    for path in _sources():
        lines = len(path.read_text().splitlines())
        if lines > MAX_FILE_LINES:
            long[str(path.relative_to(ROOT))] = lines
    assert not long, f"files over {MAX_FILE_LINES} lines (split them by what they do): {long}"


def test_no_package_function_is_over_80_lines():
    long = []
    for path in _sources():
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                lines = node.end_lineno - node.lineno + 1
                if lines > MAX_FUNCTION_LINES:
                    long.append(f"{path.relative_to(ROOT)}:{node.lineno} {node.name} ({lines} lines)")
    assert not long, f"functions over {MAX_FUNCTION_LINES} lines:\n" + "\n".join(long)


def test_ruff_check_passes():
    if importlib.util.find_spec("ruff") is None:
        pytest.skip("ruff is not installed (pip install -e '.[test]' installs it)")
    proc = subprocess.run([sys.executable, "-m", "ruff", "check", "."], cwd=ROOT, capture_output=True, text=True)
    assert proc.returncode == 0, proc.stdout + proc.stderr


def _git(*args) -> subprocess.CompletedProcess:
    return subprocess.run(["git", *args], cwd=ROOT, capture_output=True, text=True)


def test_no_development_history_in_code_tests_or_docs():
    try:
        inside = _git("rev-parse", "--is-inside-work-tree")
    except FileNotFoundError:
        pytest.skip("git is not installed")
    if inside.returncode != 0 or inside.stdout.strip() != "true":
        pytest.skip("not a git checkout")
    # --untracked: files not added yet count too, as they will on a fresh clone once committed.
    proc = _git("grep", "-nIE", "--untracked", HISTORY, "--", *HISTORY_PATHS)
    assert proc.returncode in (0, 1), proc.stderr  # 1: no match
    assert proc.stdout == "", (
        "name things by what they are, not by when they were made (no progress-report or issue numbers, "
        "no checkpoint code names):\n" + proc.stdout
    )
