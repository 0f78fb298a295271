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
