"""The docs point at things that exist: module paths, links, pictures (each stored once)."""

from __future__ import annotations

import hashlib
import importlib
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
DOCS = sorted([ROOT / "README.md", ROOT / "tasks" / "README.md", *(ROOT / "docs").glob("*.md"),
               *(ROOT / "rewards").glob("*/MODEL_CARD.md")])


def resolve(dotted: str):
    """The module or attribute a dotted ``drem_maniskill....`` name stands for (ImportError/AttributeError if none)."""
    parts = dotted.split(".")
    for cut in range(len(parts), 0, -1):
        try:
            obj = importlib.import_module(".".join(parts[:cut]))
        except ModuleNotFoundError:
            continue
        for name in parts[cut:]:
            obj = getattr(obj, name)
        return obj
    raise ImportError(dotted)


@pytest.mark.parametrize("doc", DOCS, ids=lambda p: str(p.relative_to(ROOT)))
def test_every_dotted_name_in_the_docs_exists(doc):
    names = set(re.findall(r"\bdrem_maniskill(?:\.[A-Za-z_]\w*)+", doc.read_text()))
    missing = []
    for name in sorted(names):
        try:
            resolve(name)
        except (ImportError, AttributeError):
            missing.append(name)
    assert not missing, f"{doc.relative_to(ROOT)} names what does not exist: {missing}"


@pytest.mark.parametrize("doc", DOCS, ids=lambda p: str(p.relative_to(ROOT)))
def test_every_relative_link_in_the_docs_exists(doc):
    links = re.findall(r"\]\(([^)#\s]+)(?:#[^)]*)?\)", doc.read_text())
    missing = [link for link in links if "://" not in link and not (doc.parent / link).exists()]
    assert not missing, f"{doc.relative_to(ROOT)} links to missing files: {missing}"


@pytest.mark.parametrize("doc", DOCS, ids=lambda p: str(p.relative_to(ROOT)))
def test_every_file_and_test_the_docs_name_exists(doc):
    """Paths in code spans (``drem_maniskill/...``, ``tests/...::test_x``, ``scripts/...``, ``bench/...``) exist."""
    missing = []
    for path, _, test in re.findall(r"`((?:drem_maniskill|tests|scripts|bench)/[\w/.-]+\.(?:py|sh))(::(\w+))?", doc.read_text()):
        file = ROOT / path
        if not file.exists() or (test and not re.search(rf"^(def|class) {test}\b|^{test} =", file.read_text(), re.M)):
            missing.append(path + (f"::{test}" if test else ""))
    assert not missing, f"{doc.relative_to(ROOT)} names missing files or tests: {missing}"


def test_result_pictures_are_stored_once():
    seen, twins = {}, []
    for png in sorted([*(ROOT / "docs").rglob("*.png"), *(ROOT / "rewards").rglob("*.png")]):
        digest = hashlib.sha256(png.read_bytes()).hexdigest()
        if digest in seen:
            twins.append((str(seen[digest].relative_to(ROOT)), str(png.relative_to(ROOT))))
        seen.setdefault(digest, png)
    assert not twins, f"the same picture twice (link to one instead): {twins}"
