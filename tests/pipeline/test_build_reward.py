"""``build_reward``: a task's recipe from the demo to a published reward folder, each stage resumable."""

from __future__ import annotations

import json
import time

import pytest
import torch

from drem_maniskill.drem.checkpoint import load_checkpoint
from drem_maniskill.pipeline.build_reward import PUBLISHED, build_reward, check_same_recipe, demo_stage
from drem_maniskill.pipeline.recipe import RecipeError, load_recipe, read_toml, recipe_path

STAGES = ("sample", "train", "examine", "train_image", "examine_image", "calibrate")


@pytest.mark.slow
def test_tiny_build_runs_end_to_end_and_a_second_call_skips_every_stage(tmp_path, capsys):
    out = tmp_path / "tiny"
    start = time.time()
    path = build_reward("PegInHole-v1", scale="tiny", out=out)
    took = time.time() - start
    assert path == out / "drem.pt"
    header, _ = load_checkpoint(str(path))
    assert header["env_id"] == "PegInHole-v1" and header["train"]["iterations"] == 50
    assert header["sampler"]["num_children"] == 4 and header["modalities"] == ["fixed", "wrist", "ft"]
    image, _ = load_checkpoint(str(out / "drem_image.pt"))
    assert image["modalities"] == ["fixed", "wrist"]
    assert json.loads((out / "quality.json").read_text())["seeds"] == [0]
    assert all((out / name).is_file() for name in PUBLISHED.values())
    first = capsys.readouterr().err
    assert "demo: the committed" in first and all(f"{s}: running" in first for s in STAGES)

    build_reward("PegInHole-v1", scale="tiny", out=out)
    again = capsys.readouterr().err
    assert all(f"{s}: skipped" in again for s in STAGES) and ": running" not in again
    print(f"tiny build: {took:.0f} s")


def test_outputs_of_another_recipe_are_refused(tmp_path):
    tiny = load_recipe("PegInHole-v1", "tiny")
    check_same_recipe(tmp_path / "recipe.json", tiny)
    check_same_recipe(tmp_path / "recipe.json", tiny)  # the same recipe resumes
    faster = load_recipe("PegInHole-v1", "tiny", recipe={**_raw("PegInHole-v1"), "sampler": {"workers": 2}})
    with pytest.raises(RecipeError, match="differs in sampler") as err:
        check_same_recipe(tmp_path / "recipe.json", faster)
    assert "tree.h5" in str(err.value) and "expert," not in str(err.value)  # the demo is still good
    examined = load_recipe("PegInHole-v1", "tiny", recipe={**_raw("PegInHole-v1"), "examine": {"first_seed": 5}})
    with pytest.raises(RecipeError, match=r"differs in examine\); delete what those settings made \(examination, "
                                          r"examination_image, and recipe.json\)"):
        check_same_recipe(tmp_path / "recipe.json", examined)


def test_outputs_recorded_before_a_section_existed_resume_when_it_keeps_its_defaults(tmp_path):
    recipe = load_recipe("PegInHole-v1")
    recorded = json.loads(json.dumps(recipe.to_dict()))
    del recorded["scene_swap"]  # a build made before [scene_swap] existed
    (tmp_path / "recipe.json").write_text(json.dumps(recorded))
    check_same_recipe(tmp_path / "recipe.json", recipe)
    raw = _raw("PegInHole-v1")
    raw["scene_swap"] = {"negatives": True}
    with pytest.raises(RecipeError, match=r"differs in scene_swap\); delete what those settings made \(examination"):
        check_same_recipe(tmp_path / "recipe.json", load_recipe("PegInHole-v1", recipe=raw))


def test_a_machine_setting_does_not_block_resuming(tmp_path):
    raw = _raw("PegInHole-v1")
    check_same_recipe(tmp_path / "recipe.json", load_recipe("PegInHole-v1", recipe=raw))
    raw["sampler"] = {**raw["sampler"], "workers": 2}
    raw["train"] = {**raw["train"], "threads": 2}
    check_same_recipe(tmp_path / "recipe.json", load_recipe("PegInHole-v1", recipe=raw))


def test_a_demo_of_another_task_is_refused(tmp_path):
    recipe = load_recipe("PegInHole-v1", recipe=recipe_path("USBInsertion-v1"))
    with pytest.raises(RecipeError, match="recorded on USBInsertion-v1, not PegInHole-v1"):
        demo_stage(recipe, tmp_path)


def _raw(task: str) -> dict:
    return read_toml(recipe_path(task), task)



@pytest.mark.slow
def test_a_forest_samples_a_tree_per_demo_episode_and_trains_on_all_of_them(tmp_path):
    from drem_maniskill.drem.model import ModelConfig
    from drem_maniskill.pipeline.dataset import TreeDataset
    from drem_maniskill.pipeline.recipe import GENERAL_DEFAULTS, merge

    recipe = merge(GENERAL_DEFAULTS, {"demo": {"seed": 1000, "episodes": 2, "trees": 2},
                                      "calibrate": {"enabled": False},
                                      "scales": {"tiny": {"sampler": {"max_depth": 120}}}})
    path = build_reward("PushCube-v1", scale="tiny", out=tmp_path, recipe=recipe)
    header, _ = load_checkpoint(str(path))
    model = ModelConfig(image_size=64, modalities=("fixed",))  # PushCube-v1 has one camera and no F/T
    forest, second = (TreeDataset(str(tmp_path / name), model) for name in ("tree.h5", "tree_1.h5"))
    assert [t["episode_seed"] for t in header["trees"]] == [1000, 1001]
    assert [t["nodes"] for t in header["trees"]] == [forest.tree_nodes, second.tree_nodes]
    start = forest.tree_nodes
    forest.add_trees([str(tmp_path / "tree_1.h5")], model)
    assert forest.tree_nodes == len(forest.depth) == sum(t["nodes"] for t in header["trees"])
    # One goal for the whole forest: the first episode's (h(s_G) of the reward); the second tree's goal is a node.
    assert forest.goal_index == 0 and int(forest.depth[start + second.goal_index]) == 0
    assert torch.equal(forest.images["fixed"][start:], second.images["fixed"])


def test_a_forest_needs_as_many_demo_episodes_as_trees():
    with pytest.raises(RecipeError, match=r"trees = 3 needs 1 <= trees <= episodes \(= 2\)"):
        load_recipe("PushCube-v1", recipe={"demo": {"episodes": 2, "trees": 3}})



@pytest.mark.slow
def test_scene_swap_negatives_are_written_per_tree_and_trained_on(tmp_path):
    import h5py

    from drem_maniskill.pipeline.recipe import GENERAL_DEFAULTS, merge

    recipe = merge(GENERAL_DEFAULTS, {"demo": {"seed": 1000, "episodes": 2, "trees": 2},
                                      "scene_swap": {"negatives": True, "lag": 4, "max_pairs": 30},
                                      "train": {"model": {"modalities": ["fixed", "poses"]}},
                                      "calibrate": {"enabled": False},
                                      "scales": {"tiny": {"sampler": {"max_depth": 120}}}})
    path = build_reward("PushCube-v1", scale="tiny", out=tmp_path, recipe=recipe)
    header, _ = load_checkpoint(str(path))
    counts = []
    for k in range(2):
        with h5py.File(tmp_path / "scene_swap" / f"negatives_{k}.h5") as f:
            depth, robot_depth = f["depth"][()], f["step"][()]
            assert f["poses"].shape[0] == len(depth) == 30 and (depth - robot_depth > 4).all()
            counts.append(len(depth))
    assert header["negatives"] == dict(files=["negatives_0.h5", "negatives_1.h5"], nodes=sum(counts))
    assert header["modalities"] == ["fixed", "poses"] and header["model"]["poses_size"] > 0
