"""The docs point at things that exist, and their marked code samples run.

Checked over README.md, docs/*.md, tasks/README.md and rewards/*/MODEL_CARD.md: every dotted
``drem_maniskill....`` name imports; every relative link and every repository path in a code span
(``docs/...``, ``rewards/...``, ``tasks/...``, ``drem_maniskill/...``, ``tests/...``, ``scripts/...``,
``bench/...``; paths with ``<``, ``*``, ``{`` or ``$`` are patterns and skipped) resolves; every picture
under docs/images is shown by some page and stored once; the model cards' measure tables are
what ``scripts/quality_tables.py`` prints for their own ``quality*.json``; the README's headline tables are
the shipped checkpoints' ``quality*.json`` and ``check_reward*.json`` and the SAC comparisons' ``comparison.json``.

Runnable code samples: a ```python block right after a line ``<!-- runnable -->`` is run, each in
its own Python process from the repository root, and must exit 0. Mark only samples that are
cheap: one env (the default ``num_envs=1``), a few steps, no training. Unmarked blocks are not run.
"""

from __future__ import annotations

import hashlib
import importlib
import importlib.util
import json
import os
import re
import subprocess
import sys
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
    pattern = r"`((?:drem_maniskill|tests|scripts|bench)/[\w/.-]+\.(?:py|sh))(::(\w+))?"
    for path, _, test in re.findall(pattern, doc.read_text()):
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
    """``drem_maniskill.evaluate.targets``: the one writer of the model cards' measure tables."""
    from drem_maniskill.evaluate import targets

    return targets


def _section(text: str, heading: str) -> str:
    """The text of the ``## heading...`` section of a markdown file, up to the next ``## ``."""
    start = text.index("\n## " + heading)
    end = text.find("\n## ", start + 1)
    return text[start:end if end >= 0 else len(text)]


# The cards of our tasks, which ship a DREM and an image-only checkpoint, each examined.
CARDS = sorted(p for p in (ROOT / "rewards").glob("*/MODEL_CARD.md") if (p.parent / "quality_image.json").exists())


def _body(text: str, header_start: str) -> list:
    """The body rows of every table in ``text`` whose header line starts with ``header_start``."""
    lines, out = text.split("\n"), []
    for i, line in enumerate(lines):
        if line.strip().startswith(header_start):
            rows = []
            for body in lines[i + 2:]:
                if not body.startswith("|"):
                    break
                rows.append(body.strip())
            out.append(rows)
    return out


SINGLE, SIDE = "| measure | value | target", "| measure | images + F/T | images only |"


@pytest.mark.parametrize("card", CARDS, ids=lambda p: p.parent.name)
def test_each_model_card_section_shows_the_measures_of_its_own_checkpoints_quality_file(card):
    # A table pasted from the other checkpoint's file once stood under the image-only heading.
    qt = _quality_tables()
    text = card.read_text()
    quality = json.loads((card.parent / "quality.json").read_text())
    image = json.loads((card.parent / "quality_image.json").read_text())
    checked = 0
    for heading, q in (("Quality", quality), ("The image-only checkpoint", image)):
        want = _body(qt.tables(q), SINGLE)[0]
        for rows in _body(_section(text, heading), SINGLE):
            assert rows == want, (card, heading)
            checked += 1
    want = _body(qt.tables(quality, image), SIDE)[0]
    for rows in _body(text, SIDE):
        assert rows == want, card
        checked += 1
    assert checked >= 3, f"{card}: the measure tables written by scripts/quality_tables.py are missing"


MARKER = "<!-- runnable -->"


def runnable_blocks():
    """``(doc, line, code)`` of every ```python block marked runnable in the docs."""
    out = []
    for doc in DOCS:
        lines = doc.read_text().split("\n")
        for i, line in enumerate(lines):
            if line.strip() == MARKER:
                assert lines[i + 1].strip() == "```python", f"{doc}:{i + 1}: {MARKER} must precede a ```python block"
                end = lines.index("```", i + 2)
                out.append((doc, i + 2, "\n".join(lines[i + 2:end])))
    return out


BLOCKS = runnable_blocks()


def test_the_readme_quickstart_is_marked_runnable():
    assert any(doc.name == "README.md" and doc.parent == ROOT for doc, _, _ in BLOCKS)


@pytest.mark.parametrize("doc,line,code", BLOCKS, ids=[f"{d.relative_to(ROOT)}:{n}" for d, n, _ in BLOCKS])
def test_runnable_code_samples_run(doc, line, code):
    env = dict(os.environ, OMP_WAIT_POLICY="PASSIVE")
    done = subprocess.run([sys.executable, "-c", code], cwd=ROOT, env=env, capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, f"{doc.relative_to(ROOT)}:{line} failed:\n{done.stderr[-4000:]}"


REPO_PATH = re.compile(r"`((?:docs|rewards|tasks|drem_maniskill|tests|scripts|bench)/[^`\s]*)`")


@pytest.mark.parametrize("doc", DOCS, ids=lambda p: str(p.relative_to(ROOT)))
def test_every_repository_path_in_a_code_span_exists(doc):
    missing = []
    for path in REPO_PATH.findall(doc.read_text()):
        if any(c in path for c in "<*{$"):
            continue
        path = path.split("::")[0].rstrip("/")
        if not (ROOT / path).exists():
            missing.append(path)
    assert not missing, f"{doc.relative_to(ROOT)} names paths that do not exist: {missing}"


def test_every_docs_picture_is_shown_by_a_page():
    text = "\n".join(doc.read_text() for doc in DOCS)
    pictures = sorted((ROOT / "docs" / "images").rglob("*.png"))
    unshown = [str(p.relative_to(ROOT)) for p in pictures if p.name not in text]
    assert not unshown, f"pictures no page shows (link them or remove them): {unshown}"


REPORTS = sorted((ROOT / "rewards").glob("*/check_reward*.json"))


@pytest.mark.parametrize("report", REPORTS, ids=lambda p: f"{p.parent.name}/{p.name}")
def test_each_exploit_check_report_beside_a_model_card_is_shown_in_it(report):
    # The card's table is the report's, so a rerun check that changes a number must change the card too.
    from drem_maniskill.evaluate.check_reward import markdown_table

    card = (report.parent / "MODEL_CARD.md").read_text()
    assert markdown_table(json.loads(report.read_text())) in card, report
    assert report.name in card, report


def test_the_scene_swap_row_is_printed_where_the_examination_measured_it():
    qt = _quality_tables()
    q = dict(value_order_spearman=0.99, final_reward_auroc=0.96, random_mean_reward=0.4)
    assert "reads the robot" not in qt.tables(q)
    row = [r for r in qt.tables({**q, "robot_only_over_expert": 0.998}).split("\n") if "reads the robot" in r]
    assert len(row) == 1 and "| 0.998 | well below 1 |" in row[0]


def _readme_row(first_cell: str) -> list:
    """The cells of the README table row whose first cell is ``first_cell``."""
    for line in (ROOT / "README.md").read_text().split("\n"):
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if line.startswith("|") and cells[0] == first_cell:
            return cells
    raise AssertionError(f"README.md has no table row for {first_cell}")


@pytest.mark.parametrize("quality", sorted((ROOT / "rewards").glob("*/quality*.json")),
                         ids=lambda p: f"{p.parent.name}/{p.name}")
def test_the_readme_shows_each_shipped_checkpoints_examination_and_exploit_check(quality):
    # The headline table is the files': a checkpoint re-examined or re-checked must change the README too.
    q = json.loads(quality.read_text())
    name = "drem_image.pt" if quality.stem.endswith("_image") else "drem.pt"
    cells = _readme_row(f"`{quality.parent.name}/{name}`")
    assert cells[2:4] == [f"{q['value_order_spearman']:.3f}", f"{q['final_reward_auroc']:.3f}"], cells
    report = quality.parent / quality.name.replace("quality", "check_reward")
    if report.exists():
        exploit = json.loads(report.read_text())["verdict"]["exploit"]
        assert cells[4].startswith("**exploit**" if exploit else "no exploit found"), cells


@pytest.mark.parametrize("reward", ["drem", "drem-image", "engineered", "vice", "sparse"])
def test_the_readme_shows_the_sac_comparisons_success_at_50k(reward):
    want = []
    for preset in ("state", "image"):
        for task in ("PegInHole-v1", "USBInsertion-v1"):
            table = json.loads((ROOT / "docs/results" / f"comparison_{preset}" / task / "comparison.json").read_text())
            row = next(r for r in table["rows"] if r["reward"].split(",")[0] == reward)
            assert row["final_steps"] == 50_000 and row["seeds"] == 3, row
            want.append(f"{round(100 * row['final_success'])} %")
    assert _readme_row(reward)[1:] == want


@pytest.mark.parametrize("doc", ["docs/drem.md"])
def test_recipe_keys_a_page_adds_to_the_general_recipe_build_a_sampler_and_trainer(doc):
    """Each TOML block of ``doc``, merged over the general recipe, gives a recipe whose sampler and training configs
    build."""
    import tomllib

    from drem_maniskill.pipeline.recipe import GENERAL_DEFAULTS, merge, resolve

    blocks = re.findall(r"```toml\n(.*?)```", (ROOT / doc).read_text(), re.S)
    assert blocks, f"{doc} shows no recipe keys"
    for block in map(tomllib.loads, blocks):
        recipe = resolve(merge(GENERAL_DEFAULTS, block), "SquarePegInHole-v1", "full", doc)
        sampler = recipe.sampler_config()
        recipe.train_config()
        for name in block.get("sampler", {}).get("phases", {}):
            assert name in sampler.phases, f"{doc}: phase {name} did not reach the sampler config"
