"""The experiment scripts' own bookkeeping (experiments/ is not a package: its folder goes on the path)."""

from __future__ import annotations

import json
import os
import signal
import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "experiments"))


def test_a_build_stopped_with_sigterm_still_adds_the_time_it_spent(tmp_path, monkeypatch):
    """timed_build: a SIGTERM mid-build unwinds (exit 143) after adding its time to what earlier invocations spent."""
    import general_recipe

    import drem_maniskill.pipeline.build_reward as build_module

    def killed(task, scale, out, recipe):
        os.kill(os.getpid(), signal.SIGTERM)
        raise AssertionError("SIGTERM did not stop the build")

    (tmp_path / "build_seconds.json").write_text(json.dumps({"seconds": 100.0}))
    monkeypatch.setattr(build_module, "build_reward", killed)
    before = signal.getsignal(signal.SIGTERM)
    with pytest.raises(SystemExit) as stop:
        general_recipe.timed_build("PegInHole-v1", tmp_path, {})
    assert stop.value.code == 128 + signal.SIGTERM
    assert json.loads((tmp_path / "build_seconds.json").read_text())["seconds"] >= 100.0
    assert signal.getsignal(signal.SIGTERM) == before


def test_a_kept_build_is_restored_instead_of_built_and_one_of_another_recipe_is_refused(tmp_path, monkeypatch):
    """timed_build with ``keep``: a finished build is copied there; a work folder without it (another machine)
    takes it back without building, a rerun builds nothing either, and a kept build of another recipe raises."""
    import general_recipe

    import drem_maniskill.pipeline.build_reward as build_module
    from drem_maniskill.pipeline.recipe import RecipeError, load_recipe

    recipe = {"train": {"iterations": 123}}

    def built(task, scale, out, recipe):
        out.mkdir(parents=True, exist_ok=True)
        (out / "recipe.json").write_text(json.dumps(load_recipe(task, scale, recipe).to_dict()))
        for name in ("drem.pt", "quality.json", "examination.png"):
            (out / name).write_text(name)
        return out / "drem.pt"

    monkeypatch.setattr(build_module, "build_reward", built)
    keep = tmp_path / "keep"
    general_recipe.timed_build("PegInHole-v1", tmp_path / "first", recipe, keep=keep)
    assert sorted(p.name for p in keep.iterdir()) == sorted(general_recipe.KEPT)

    def never(*args, **kwargs):
        raise AssertionError("built again although a finished build was kept")

    monkeypatch.setattr(build_module, "build_reward", never)
    for _ in range(2):  # restored, then found finished in the work folder
        checkpoint, seconds = general_recipe.timed_build("PegInHole-v1", tmp_path / "second", recipe, keep=keep)
        assert checkpoint.read_text() == "drem.pt" and seconds >= 0.0
    with pytest.raises(RecipeError, match="another recipe"):
        general_recipe.timed_build("PegInHole-v1", tmp_path / "third", {"train": {"iterations": 7}}, keep=keep)
    assert not (tmp_path / "third" / "drem.pt").exists()
