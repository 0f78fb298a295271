"""A wheel can build a reward: it carries the recipes and committed demos, and ``build-reward`` finds them installed.

The end-to-end test builds the wheel from a copy of the sources, installs it into a fresh venv that sees this
venv's dependencies but not this checkout, and runs ``drem-maniskill demo --scale tiny`` there: the README's demo,
whose reward build reads the installed recipe and demo, ending in its plots.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import sysconfig
from pathlib import Path

import pytest

from drem_maniskill.drem.checkpoint import load_checkpoint
from drem_maniskill.pipeline import recipe as recipe_module
from drem_maniskill.pipeline.build_reward import PUBLISHED
from drem_maniskill.pipeline.recipe import load_recipe, recipe_path, task_folder

ROOT = Path(__file__).resolve().parents[1]
SHARE_TASKS = "share/drem-maniskill/tasks"

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    tomllib = pytest.importorskip("tomli")


def data_files() -> dict:
    """``pyproject.toml``'s ``[tool.setuptools.data-files]``: install folder -> files."""
    return tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]["data-files"]


def test_the_wheels_data_files_carry_every_recipe_and_committed_demo():
    """Every ``tasks/<id>/`` file a build reads (recipe.toml, expert.h5, expert.json) travels with a wheel."""
    listed = {folder: set(names) for folder, names in data_files().items() if folder.startswith(SHARE_TASKS + "/")}
    on_disk = {f"{SHARE_TASKS}/{p.name}": {f"tasks/{p.name}/{f.name}" for f in p.iterdir() if f.is_file()}
               for p in (ROOT / "tasks").iterdir() if p.is_dir()}
    assert listed == on_disk
    for folder, names in listed.items():  # a recipe, a demo (a task built with the general recipe), or both
        task = Path(folder).name
        assert f"tasks/{task}/recipe.toml" in names or f"tasks/{task}/expert.h5" in names, folder


def test_a_task_folder_is_the_checkouts_first_then_the_installed_one(tmp_path, monkeypatch):
    checkout, share = tmp_path / "checkout", tmp_path / "share"
    for folder in (checkout / "Both-v1", share / "Both-v1", share / "Installed-v1"):
        folder.mkdir(parents=True)
    monkeypatch.setattr(recipe_module, "TASKS_DIRS", (checkout, share))
    assert task_folder("Both-v1") == checkout / "Both-v1"
    assert recipe_path("Installed-v1") == share / "Installed-v1" / "recipe.toml"
    assert task_folder("Nowhere-v1") == checkout / "Nowhere-v1"  # where a missing recipe is reported
    assert load_recipe("Installed-v1", recipe={"demo": {"expert": "expert.h5"}}).expert_file() == (
        share / "Installed-v1" / "expert.h5")


def _copy_sources(dest: Path) -> Path:
    """The files a wheel is built from (package, metadata, data files), copied so that the checkout stays untouched."""
    dest.mkdir(parents=True)
    for name in ("pyproject.toml", "README.md", "LICENSE"):
        if (ROOT / name).is_file():
            shutil.copy2(ROOT / name, dest / name)
    shutil.copytree(ROOT / "drem_maniskill", dest / "drem_maniskill",
                    ignore=shutil.ignore_patterns("__pycache__", "*.pyc"))
    for names in data_files().values():
        for name in names:
            (dest / name).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(ROOT / name, dest / name)
    return dest


def _snapshot(*folders: Path) -> tuple:
    """The files under ``folders``, and the modification time of each that a build writes (its published names)."""
    written = {*PUBLISHED.values(), "recipe.json"}
    files = sorted(p for f in folders for p in f.rglob("*"))
    return [str(p) for p in files], {str(p): p.stat().st_mtime_ns for p in files if p.name in written}


def _run(args, cwd, env=None, timeout=600) -> subprocess.CompletedProcess:
    """Run ``args``; fail with the tail of its output unless it succeeds."""
    proc = subprocess.run([str(a) for a in args], cwd=cwd, env=env, capture_output=True, text=True, timeout=timeout)
    assert proc.returncode == 0, f"{args} exited {proc.returncode}:\n{proc.stdout[-3000:]}\n{proc.stderr[-4000:]}"
    return proc


def _wheel_venv(tmp_path: Path) -> Path:
    """A venv holding only the wheel built from these sources; the dependencies come from this venv's site-packages.

    A plain path line in a ``.pth`` file adds that folder without running the ``.pth`` files inside it, so this
    venv's editable install (an import hook set up by such a file) stays out and the wheel's copy is imported.
    """
    src = _copy_sources(tmp_path / "src")
    _run([sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation", "--no-index",
          "-w", tmp_path / "dist", src], cwd=tmp_path)
    (wheel,) = (tmp_path / "dist").glob("drem_maniskill-*.whl")
    venv = tmp_path / "venv"
    _run([sys.executable, "-m", "venv", venv], cwd=tmp_path)
    python = venv / "bin" / "python"
    # Installed before the dependencies become visible, so pip never sees this venv's drem-maniskill.
    _run([python, "-m", "pip", "install", "--no-deps", "--no-index", "--quiet", wheel], cwd=tmp_path)
    purelib = _run([python, "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"], cwd=tmp_path)
    (Path(purelib.stdout.strip()) / "drem_dependencies.pth").write_text(sysconfig.get_paths()["purelib"] + "\n")
    return venv


@pytest.mark.slow
def test_an_installed_wheel_runs_the_demo_building_a_tiny_reward_from_its_own_recipe_and_demo(tmp_path):
    venv = _wheel_venv(tmp_path)
    work = tmp_path / "work"
    work.mkdir()
    # Nothing points at the checkout; the rest of the environment (Vulkan for SAPIEN among it) is inherited.
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "PYTHONHOME", "VIRTUAL_ENV")}
    env.update(PATH=f"{venv / 'bin'}{os.pathsep}{env.get('PATH', '')}", PYTHONNOUSERSITE="1")
    where = _run([venv / "bin" / "python", "-c", "import drem_maniskill; print(drem_maniskill.__file__)"], work, env)
    assert Path(where.stdout.strip()).is_relative_to(venv), where.stdout

    checkout = _snapshot(ROOT / "rewards", ROOT / "tasks")
    build = _run([venv / "bin" / "drem-maniskill", "demo", "--out", work / "demo", "--tasks", "PegInHole-v1",
                  "--scale", "tiny"], work, env, timeout=1800)
    installed = venv / SHARE_TASKS / "PegInHole-v1"
    assert f"recipe {installed / 'recipe.toml'}, scale tiny" in build.stderr, build.stderr[-3000:]
    assert f"demo: the committed {installed / 'expert.h5'}" in build.stderr, build.stderr[-3000:]
    assert "reward checkpoint:" in build.stdout, build.stdout[-3000:]
    out = work / "demo" / "PegInHole-v1"
    assert all((out / name).is_file() for name in PUBLISHED.values())
    summary = json.loads((work / "demo" / "summary.json").read_text())
    for plot in summary["PegInHole-v1"]["plots"]:  # the demo's drawings and the examination's
        assert Path(plot).is_relative_to(out) and Path(plot).stat().st_size > 2_000, plot
    header, _ = load_checkpoint(str(out / "drem.pt"))
    assert header["env_id"] == "PegInHole-v1" and header["train"]["iterations"] == 50
    assert header["sampler"]["num_children"] == 4 and header["modalities"] == ["fixed", "wrist", "ft"]
    assert load_checkpoint(str(out / "drem_image.pt"))[0]["modalities"] == ["fixed", "wrist"]  # the recipe's twin
    assert _snapshot(ROOT / "rewards", ROOT / "tasks") == checkout
