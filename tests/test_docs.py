"""The docs point at things that exist: module paths, links, pictures (each stored once)."""

from __future__ import annotations

import hashlib
import importlib
import importlib.util
import json
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


def _quality_tables():
    """``scripts/quality_tables.py`` as a module: the one writer of the model cards' measure tables."""
    spec = importlib.util.spec_from_file_location("quality_tables", ROOT / "scripts" / "quality_tables.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _card_tables(text: str, header: str) -> list:
    """The body rows of every table in ``text`` whose header line is ``header``."""
    lines, out = text.split("\n"), []
    for i, line in enumerate(lines):
        if line.strip() == header:
            rows = []
            for body in lines[i + 2:]:
                if not body.startswith("|"):
                    break
                rows.append(body.strip())
            out.append(rows)
    return out


def _section(text: str, heading: str) -> str:
    """The text of the ``## heading...`` section of a markdown file, up to the next ``## ``."""
    start = text.index("\n## " + heading)
    end = text.find("\n## ", start + 1)
    return text[start:end if end >= 0 else len(text)]


# The cards of our tasks, which ship a DREM and an image-only checkpoint, each examined.
CARDS = sorted(p for p in (ROOT / "rewards").glob("*/MODEL_CARD.md") if (p.parent / "quality_image.json").exists())


@pytest.mark.parametrize("card", CARDS, ids=lambda p: p.parent.name)
def test_each_model_card_section_shows_the_measures_of_its_own_checkpoints_quality_file(card):
    # Stop 29's USB card showed drem.pt's measures under the image-only heading: a table pasted from the wrong file.
    qt = _quality_tables()
    text = card.read_text()
    quality = json.loads((card.parent / "quality.json").read_text())
    image = json.loads((card.parent / "quality_image.json").read_text())
    single = "| measure | value | target (issue 12) |"
    side = "| measure | images + F/T | images only |"
    checked = 0
    for heading, q in (("Quality", quality), ("The image-only checkpoint", image)):
        want = _card_tables(qt.tables(q), single)[0]
        for rows in _card_tables(_section(text, heading), single):
            assert rows == want, (card, heading)
            checked += 1
    want = _card_tables(qt.tables(quality, image), side)[0]
    for rows in _card_tables(text, side):
        assert rows == want, card
        checked += 1
    assert checked > 0, f"{card}: no measure table written by scripts/quality_tables.py"
