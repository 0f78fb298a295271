"""The test session's order: the slowest modules first, from the per-module seconds of a run's report."""

from __future__ import annotations

import runpy
from pathlib import Path
from types import SimpleNamespace

from tests import conftest

DURATIONS = runpy.run_path(str(Path(__file__).resolve().parents[1] / "scripts" / "test_durations.py"))

REPORT = """\
============================= slowest durations ==============================
120.50s call     tests/rl/test_sweep.py::test_a_sweep_killed
30.25s setup    tests/pipeline/test_poses.py::test_the_tree_holds_poses
10.00s call     tests/rl/test_sweep.py::test_start_report[PegInHole-v1]
2.00s teardown tests/pipeline/test_poses.py::test_the_tree_holds_poses
(3 durations < 0.005s hidden.  Use -vv to show these durations.)
654 passed, 3 skipped in 1000.50s (0:16:40)
"""


def test_a_report_sums_each_modules_setup_call_and_teardown():
    assert DURATIONS["module_seconds"](REPORT) == {"tests/rl/test_sweep.py": 130.5,
                                                   "tests/pipeline/test_poses.py": 32.25}
    assert DURATIONS["module_seconds"]("654 passed in 3.00s") == {}


def _item(nodeid: str, slow: bool):
    return SimpleNamespace(nodeid=nodeid, get_closest_marker=lambda name: object() if slow and name == "slow" else None)


def test_the_slowest_modules_run_first_and_in_each_its_slow_tests_first(monkeypatch):
    monkeypatch.setattr(conftest, "DURATIONS", {"tests/a.py": 5, "tests/b.py": 300, "tests/c.py": 40})
    items = [_item("tests/a.py::quick", False), _item("tests/new.py::quick", False), _item("tests/c.py::quick", False),
             _item("tests/c.py::slow", True), _item("tests/b.py::quick", False), _item("tests/b.py::slow[x]", True)]
    conftest.pytest_collection_modifyitems(None, items)
    assert [i.nodeid for i in items] == ["tests/b.py::slow[x]", "tests/b.py::quick", "tests/c.py::slow",
                                         "tests/c.py::quick", "tests/a.py::quick", "tests/new.py::quick"]


def test_the_committed_durations_name_test_modules_that_exist():
    root = Path(__file__).resolve().parents[1]
    assert conftest.DURATIONS and all((root / module).is_file() for module in conftest.DURATIONS)
