"""Recipes as data: every shipped checkpoint's header matches its task's recipe, and a bad recipe fails clearly.

The header-vs-recipe test pins the model card's "how it was made", the recipe file and the checkpoint
together: a change to one of them (or to a config class's defaults) that the others do not follow fails here.
"""

from __future__ import annotations

import json
import re
from dataclasses import asdict, fields
from pathlib import Path

import pytest

from drem_maniskill.drem.checkpoint import load_checkpoint
from drem_maniskill.drem.model import ModelConfig
from drem_maniskill.experts.control import ee_control_kwargs
from drem_maniskill.pipeline.recipe import GENERAL, TASKS_DIRS, RecipeError, load_recipe, recipe_path
from drem_maniskill.pipeline.train_reward import with_defaults
from drem_maniskill.pipeline.tree.config import SamplerConfig
from drem_maniskill.pipeline.tree.phases import PHASES

ROOT = Path(__file__).resolve().parents[2]
REWARDS = ROOT / "rewards"
SHIPPED = sorted(p.name for p in REWARDS.iterdir() if (p / "drem.pt").is_file())
# Settings of the machine a checkpoint was made on, not of the checkpoint: the USB tree was regrown with two
# sampler processes, and the thread count and device only change how fast training runs.
MACHINE = {"workers", "threads", "device"}


def _without(d: dict, keys=MACHINE) -> dict:
    return {k: v for k, v in d.items() if k not in keys}


def _recorded_sampler(recorded: dict) -> dict:
    """The sampler settings a checkpoint header records, in ``SamplerConfig``'s dict form.

    The shipped checkpoints' headers record each phase setting as a top-level ``<phase>_<field>`` key (the goal
    presses' count as ``goal_presses``): they keep the bytes they shipped with, which committed runs pin by sha256.
    """
    if "phases" in recorded:
        return recorded
    core = {f.name for f in fields(SamplerConfig)}
    phases: dict = {}
    for key, value in recorded.items():
        if key == "goal_presses":
            phases.setdefault(key, {})["count"] = value
        elif key not in core:
            name = next(n for n in PHASES if key.startswith(n + "_"))
            phases.setdefault(name, {})[key[len(name) + 1:]] = value
    return {**{k: v for k, v in recorded.items() if k in core}, "phases": phases}


def _shipped_files():
    for task in SHIPPED:
        yield task, "drem.pt", "quality.json"
        if (REWARDS / task / "drem_image.pt").is_file():
            yield task, "drem_image.pt", "quality_image.json"


@pytest.mark.parametrize("task,checkpoint,quality", list(_shipped_files()))
def test_shipped_checkpoint_header_matches_its_recipe(task, checkpoint, quality):
    recipe = load_recipe(task)
    header, _ = load_checkpoint(str(REWARDS / task / checkpoint))
    recorded = SamplerConfig.from_dict(_recorded_sampler(header["sampler"]))
    assert _without(recorded.to_dict()) == _without(recipe.sampler_config().to_dict())
    twin = checkpoint == "drem_image.pt"
    config = recipe.train_config(modalities=recipe.image_twin["modalities"] if twin else None)
    # Read as loading reads it: a field a header predates takes the value it was trained with (its default; the
    # model's init: PyTorch's).
    unread = MACHINE | {"model"}
    assert _without(with_defaults(header["train"]), unread) == _without(asdict(config), unread)
    model = ModelConfig.from_dict(header["model"]).to_dict()
    assert json.loads(json.dumps(model)) == json.loads(json.dumps(config.model.to_dict()))
    assert header["image_size"] == config.model.image_size and header["modalities"] == list(config.model.modalities)
    assert json.loads((REWARDS / task / quality).read_text())["seeds"] == list(recipe.exam_seeds())
    assert header["env_kwargs"] == _demo_env_kwargs(recipe)


def _demo_env_kwargs(recipe) -> dict:
    """The env kwargs the recipe's demo was (committed) or would be (recorded) made with."""
    expert = recipe.expert_file()
    if expert is not None:
        meta = json.loads(expert.with_suffix(".json").read_text())
        episodes, first = meta["episodes"], recipe.demo["seed"]
        assert [e["episode_seed"] for e in episodes] == list(range(first, first + len(episodes)))
        assert len(episodes) == recipe.demo["episodes"] and meta["env_info"]["env_id"] == recipe.task
        return meta["env_info"]["env_kwargs"]
    return {"obs_mode": "rgb", "render_mode": None, **ee_control_kwargs(recipe.task, recipe.demo["env_kwargs"])}


@pytest.mark.parametrize("task", SHIPPED)
def test_shipped_files_follow_the_recipe(task):
    recipe = load_recipe(task)
    assert (REWARDS / task / "drem_image.pt").is_file() == recipe.image_twin["enabled"]
    assert (REWARDS / task / "support.json").is_file() == recipe.calibrate["enabled"]


@pytest.mark.parametrize("task", sorted(p.parent.name for p in TASKS_DIRS[0].glob("*/recipe.toml")))
@pytest.mark.parametrize("scale", ["full", "demo", "tiny"])
def test_every_recipe_loads_at_every_scale(task, scale):
    recipe = load_recipe(task, scale)
    assert recipe.sampler_config().num_children > 0 and recipe.train_config().iterations > 0
    if scale != "full":
        assert recipe.train_config().iterations <= 500 and recipe.examine["episodes"] <= 3


def test_every_shipped_reward_has_a_recipe():
    assert all(recipe_path(task).is_file() for task in SHIPPED)


def test_scales_merge_over_the_recipe():
    full, tiny = load_recipe("USBInsertion-v1"), load_recipe("USBInsertion-v1", "tiny")
    assert tiny.sampler["phases"]["face"]["depth"] == 1 and full.sampler["phases"]["face"]["depth"] == 8
    assert tiny.sampler["expert_step_scale"] == full.sampler["expert_step_scale"] == 4.0  # kept where not overridden
    assert load_recipe("USBInsertion-v1", "demo").sampler_config().phases_on() == {}  # the demo runs the paper's loop


def _write(tmp_path, text: str) -> Path:
    path = tmp_path / "recipe.toml"
    path.write_text(text)
    return path


@pytest.mark.parametrize("text,names", [
    ("[train]\niteratons = 5\n", ["iteratons", "iterations", "[train]"]),
    ("[sampler]\nface_depth = 8\n", ["face_depth", "num_children", "[sampler]"]),
    ("[sampler.phases.face]\ndeph = 8\n", ["deph", "depth", "phases"]),
    ("[sampler.phases.flip]\ndepth = 8\n", ["flip", "goal_presses"]),
    ("[trian]\niterations = 5\n", ["[trian]", "sampler"]),
    ("[examine]\nepisodes = \"20\"\n", ["episodes", "integer"]),
    ("[scales.tiny.train]\nitrations = 4\n", ["[scales.tiny]", "itrations"]),
    ("[train.model]\nmodalities = \"ft\"\n", ["modalities", "list"]),
])
def test_a_bad_key_names_the_file_the_key_and_the_valid_ones(tmp_path, text, names):
    path = _write(tmp_path, text)
    with pytest.raises(RecipeError) as err:
        load_recipe("PegInHole-v1", recipe=path)
    for name in [str(path), *names]:
        assert name in str(err.value)


def test_a_bad_value_names_the_file_and_the_scale(tmp_path):
    path = _write(tmp_path, "[scales.tiny.train.model]\nmodalities = [\"depth\"]\n")
    load_recipe("PegInHole-v1", recipe=path)
    with pytest.raises(RecipeError, match=re.escape(f"{path} (scale tiny): modalities must be")):
        load_recipe("PegInHole-v1", "tiny", recipe=path)


def test_an_unknown_scale_lists_the_scales(tmp_path):
    path = _write(tmp_path, "[scales.tiny.train]\niterations = 4\n")
    with pytest.raises(RecipeError, match=r"no scale 'huge'.*\['full', 'tiny'\]"):
        load_recipe("PegInHole-v1", "huge", recipe=path)


def test_a_task_without_a_recipe_file_gets_the_general_recipe_and_a_missing_file_is_named(tmp_path):
    general = load_recipe("NoRecipe-v1", "tiny")
    assert general.source == GENERAL and general.to_dict() == load_recipe("NoRecipe-v1", "tiny", GENERAL).to_dict()
    assert general.expert_file() is None
    full, demo = load_recipe("NoRecipe-v1"), load_recipe("NoRecipe-v1", "demo")
    assert full.train_config().iterations == 20_000 and full.sampler_config().num_children == 100
    assert full.sampler_config().even_path and full.sampler_config().expert_step_scale == 4.0
    assert list(full.sampler_config().phases_on()) == list(general.sampler_config().phases_on()) == ["outward"]
    assert demo.sampler_config().phases_on() == {}  # make demo's minutes: no outward depths
    for scale in (general, demo, full):  # no phase of the general recipe asks the task for its socket geometry
        assert not any(PHASES[name].needs_geometry for name in scale.sampler_config().phases_on())
    assert load_recipe("PegInHole-v1").source.endswith("tasks/PegInHole-v1/recipe.toml")  # a recipe file comes first
    with pytest.raises(RecipeError) as err:
        load_recipe("PegInHole-v1", recipe=tmp_path / "nothere.toml")
    assert "nothere.toml" in str(err.value) and "does not exist" in str(err.value)


def test_invalid_toml_names_the_file(tmp_path):
    path = _write(tmp_path, "[train\n")
    with pytest.raises(RecipeError, match="not valid TOML"):
        load_recipe("PegInHole-v1", recipe=path)
