"""The source stays readable: short files and functions, ruff clean, one atomic writer, no development history.

A file in ``drem_maniskill/`` is at most 400 lines and a function or method at most 60 (def line
to last line); ``ruff check`` (the ``[tool.ruff]`` settings of pyproject.toml) passes on the
repository; every temp-file-and-rename of the package is ``drem_maniskill.utils.atomic``'s; and the
code, tests, scripts, tasks, rewards and docs name things by what they are, never by when they were
made: no progress-report numbers, issue numbers or checkpoint code names.
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

MAX_FILE_LINES = 400
MAX_FUNCTION_LINES = 60
# The one module that writes a temp file and renames it over its target; every other writer calls it.
ATOMIC_WRITER = "drem_maniskill/utils/atomic.py"

# Progress-report numbers, issue numbers and the checkpoint code names. The names are written with
# brackets so that this file does not match its own pattern.
# A code name may sit inside a JSON key (``last_20_<name>``), so "_" counts as a boundary too.
HISTORY = r"\b[Ss]tops? [0-9]+|\b[Ii]ssues? [0-9]+|(^|[^A-Za-z0-9])(G[T]|G[F]|G[2])([^A-Za-z0-9]|$)"
HISTORY_PATHS = ["drem_maniskill/", "tests/", "scripts/", "tasks/", "rewards/", "docs/", "README.md", "bench/",
                 "experiments/", "CHANGELOG.md", "Makefile", "pyproject.toml", ".ci/"]


def _sources() -> list:
    return sorted(PACKAGE.rglob("*.py"))


def test_no_package_file_is_over_400_lines():
    long = {}
    for path in _sources():
        lines = len(path.read_text().splitlines())
        if lines > MAX_FILE_LINES:
            long[str(path.relative_to(ROOT))] = lines
    assert not long, f"files over {MAX_FILE_LINES} lines (split them by what they do): {long}"


def test_no_package_function_is_over_60_lines():
    long = []
    for path in _sources():
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                lines = node.end_lineno - node.lineno + 1
                if lines > MAX_FUNCTION_LINES:
                    long.append(f"{path.relative_to(ROOT)}:{node.lineno} {node.name} ({lines} lines)")
    assert not long, f"functions over {MAX_FUNCTION_LINES} lines:\n" + "\n".join(long)


def _is_str(node: ast.AST) -> bool:
    return isinstance(node, ast.Constant) and isinstance(node.value, str)


def _renames(tree: ast.AST) -> list:
    """``(line, what)`` of each temp-file-and-rename in a parsed module.

    ``os.replace``/``os.rename`` (called or imported), any ``<x>.rename(...)``, ``tempfile.mkstemp`` /
    ``NamedTemporaryFile``, and ``<x>.replace(<y>)``, ``Path.replace``'s form: one positional argument that is not
    a string literal, on a receiver that is neither ``dataclasses`` nor a string literal (``str.replace`` takes
    two, ``dataclasses.replace`` one object plus keywords).
    """
    found = []
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom) and node.module in ("os", "tempfile"):
            found += [(node.lineno, f"from {node.module} import {alias.name}") for alias in node.names
                      if alias.name in ("replace", "rename", "mkstemp", "NamedTemporaryFile")]
        if not isinstance(node, ast.Call) or not isinstance(node.func, ast.Attribute):
            continue
        name, receiver = node.func.attr, node.func.value
        module = receiver.id if isinstance(receiver, ast.Name) else None
        if module == "os" and name in ("replace", "rename"):
            found.append((node.lineno, f"os.{name}"))
        elif module == "tempfile" and name in ("mkstemp", "NamedTemporaryFile"):
            found.append((node.lineno, f"tempfile.{name}"))
        elif name == "rename":
            found.append((node.lineno, ".rename()"))
        elif (name == "replace" and module != "dataclasses" and not _is_str(receiver) and len(node.args) == 1
              and not isinstance(node.args[0], ast.Starred) and not _is_str(node.args[0])):
            found.append((node.lineno, ".replace(<path>)"))
    return found


def test_rename_finder_tells_path_renames_from_other_replaces():
    flagged = """
import os, tempfile
from os import replace
os.replace(tmp, path)
os.rename(tmp, path)
tmp.replace(path)
Path(tmp).rename(path)
fd, name = tempfile.mkstemp(dir=folder)
f = tempfile.NamedTemporaryFile("w", delete=False)
"""
    kept = """
import dataclasses
dataclasses.replace(config, seed=1)
replace(config, seed=1)
text.replace("_", "-")
name.replace(old, new)
"a-b".replace(sep, "_")
stamp.replace(tzinfo=None)
"""
    assert len(_renames(ast.parse(flagged))) == 7
    assert _renames(ast.parse(kept)) == []


def test_temp_file_and_rename_only_in_the_atomic_writer():
    found = []
    for path in _sources():
        name = path.relative_to(ROOT).as_posix()
        if name != ATOMIC_WRITER:
            found += [f"{name}:{line} {what}" for line, what in _renames(ast.parse(path.read_text(), str(path)))]
    assert not found, ("write through drem_maniskill.utils.atomic (atomic_path, write_text, write_json, copy_file, "
                       "promote) instead of a temp file and a rename of its own:\n" + "\n".join(found))


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
