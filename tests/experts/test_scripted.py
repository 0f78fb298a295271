"""The scripted policies of our tasks."""

from __future__ import annotations

import pytest

from tests.conftest import TASKS, make_env, run_policy


@pytest.mark.parametrize("task", TASKS)
def test_expert_succeeds_on_a_few_seeds(task):
    env = make_env(task, obs_mode="state_dict")
    wins = sum(run_policy(env, "expert", seed=100 + s)[1]["success"].item() for s in range(5))
    assert wins >= 5 - (1 if task == "USBInsertion-v1" else 0)
