"""``make demo`` takes its DREM settings from each task's recipe at the ``demo`` scale, at a few minutes per task."""

from __future__ import annotations

from dataclasses import asdict

import pytest

from drem_maniskill.envs import TASKS
from drem_maniskill.pipeline import SamplerConfig
from drem_maniskill.pipeline.recipe import RecipeError, load_recipe, recipe_path
from drem_maniskill.pipeline.train_reward import TrainConfig


@pytest.mark.parametrize("task", [task for task in TASKS if recipe_path(task).is_file()])
def test_the_demo_scale_is_the_quick_presets_at_500_iterations(task):
    recipe = load_recipe(task, "demo")
    # The paper's loop alone with 24 children per seed, following the expert's step and held to the depth
    # limit (80) as the shipped trees are.
    expected = SamplerConfig.preset("quick", expert_step_scale=4.0, max_depth=80)
    assert recipe.sampler_config().to_dict() == expected.to_dict()
    quick = asdict(TrainConfig.preset("quick", iterations=500))
    quick["model"]["modalities"] = ("fixed", "wrist", "ft")
    # threads 0: torch's default, every core, as the demo always trained.
    assert recipe.train_config().threads == 0
    assert {**asdict(recipe.train_config()), "threads": None} == quick
    assert recipe.examine["episodes"] == 3


def test_an_unknown_demo_scale_fails_before_recording(tmp_path):
    from drem_maniskill.demo import run_demo

    with pytest.raises(RecipeError, match="no scale 'huge'"):
        run_demo(out=str(tmp_path), tasks=TASKS[:1], scale="huge")
    assert not any(tmp_path.iterdir())
