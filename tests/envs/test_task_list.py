"""``envs.TASKS`` is the one task list: the registrations, the shipped data and the wheel's data files agree with it."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest
from mani_skill.utils.registration import REGISTERED_ENVS

from drem_maniskill.envs import (
    DREM_ALIASES,
    TASK_FILES,
    TASKS,
    InsertionEnv,
    drem_env_id,
    is_insertion_task,
)

from tests.conftest import SHIPPED_TASKS

ROOT = Path(__file__).resolve().parents[2]

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    tomllib = pytest.importorskip("tomli")


def data_files() -> dict:
    """``pyproject.toml``'s ``[tool.setuptools.data-files]``: install folder -> files."""
    return tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]["data-files"]


def test_every_task_of_the_list_is_registered_from_its_file():
    assert TASKS == tuple(TASK_FILES)
    for task, module in TASK_FILES.items():
        spec = REGISTERED_ENVS[task]
        assert issubclass(spec.cls, InsertionEnv) and spec.cls.env_id == task
        assert spec.cls.__module__ == f"drem_maniskill.envs.{module}"
        assert is_insertion_task(task)


def test_every_task_has_its_drem_alias():
    assert DREM_ALIASES == {drem_env_id(t): t for t in TASKS}
    for alias, task in DREM_ALIASES.items():
        assert REGISTERED_ENVS[alias].max_episode_steps == REGISTERED_ENVS[task].max_episode_steps


@pytest.mark.parametrize("task", TASKS)
def test_every_task_ships_its_demo(task):
    assert (ROOT / "tasks" / task / "expert.h5").is_file() and (ROOT / "tasks" / task / "expert.json").is_file()


@pytest.mark.parametrize("task", SHIPPED_TASKS)
def test_a_task_that_ships_a_reward_ships_all_of_it(task):
    for name in ("drem.pt", "drem_image.pt", "MODEL_CARD.md", "quality.json", "examination.png", "support.json"):
        assert (ROOT / "rewards" / task / name).is_file(), f"rewards/{task}/{name} is missing"


def test_the_wheels_data_files_are_the_rewards_folder():
    """Every rewards/<id>/ folder travels with a wheel, with its checkpoints and card, and nothing else does."""
    files = {k: v for k, v in data_files().items() if k.startswith("share/drem-maniskill/rewards/")}
    shipped = {p.name for p in (ROOT / "rewards").iterdir() if p.is_dir()}
    assert {k.rsplit("/", 1)[-1] for k in files} == shipped
    assert set(SHIPPED_TASKS) <= shipped
    for folder, names in files.items():
        task = folder.rsplit("/", 1)[-1]
        assert folder == f"share/drem-maniskill/rewards/{task}"
        # support.json: the drem-guarded reward's thresholds, read beside the checkpoint.
        on_disk = {f"rewards/{task}/{p.name}" for p in (ROOT / "rewards" / task).iterdir()
                   if p.suffix in (".pt", ".md") or p.name == "support.json"}
        assert set(names) == on_disk, f"{folder}: pyproject lists {sorted(names)}, rewards/{task} has {sorted(on_disk)}"
        if task in TASKS:
            assert f"rewards/{task}/drem_image.pt" in names


def test_the_stock_checkpoints_are_for_maniskills_own_tasks():
    """rewards/ folders not in TASKS are ManiSkill tasks of their own (with a shipped image-only checkpoint)."""
    for task in {p.name for p in (ROOT / "rewards").iterdir() if p.is_dir()} - set(TASKS):
        assert task in REGISTERED_ENVS and not is_insertion_task(task)
