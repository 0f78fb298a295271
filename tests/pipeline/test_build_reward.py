"""``build_reward``: a task's recipe from the demo to a reward folder, each stage resumable; published on request."""

from __future__ import annotations

import hashlib
import json
import time
from pathlib import Path

import pytest
import torch

import drem_maniskill.pipeline.build_reward as build_module
from drem_maniskill.drem.checkpoint import load_checkpoint
from drem_maniskill.pipeline.build_reward import PUBLISHED, STAGES, build_reward, check_same_recipe, demo_stage
from drem_maniskill.pipeline.recipe import SECTIONS, RecipeError, load_recipe, read_toml, recipe_path

ROOT = Path(__file__).resolve().parents[2]

LOGGED = ("sample", "train", "examine", "train_image", "examine_image", "calibrate")


@pytest.mark.slow
def test_a_task_without_a_recipe_builds_a_tiny_general_reward_without_its_geometry_and_a_rerun_skips_every_stage(
        tmp_path, capsys, monkeypatch):
    """The general recipe on a task with no recipe file, end to end, its sampler unable to read the geometry; the
    same call again skips every stage. (A recipe file's tiny build, image twin included: tests/test_wheel.py.)"""
    from drem_maniskill.envs.adapter import EnvAdapter

    def no_geometry(self):
        raise AssertionError("the general recipe asked the task for its socket geometry")

    monkeypatch.setattr(EnvAdapter, "socket_geometry", no_geometry)
    task = "DPegInHole-v1"
    recipe = load_recipe(task, "tiny")
    # In this process (one worker), so the sampler's env is the patched one.
    assert not recipe_path(task).is_file() and recipe.source == "default" and recipe.sampler_config().workers == 1
    out = tmp_path / "general"
    start = time.time()
    path = build_reward(task, scale="tiny", out=out)
    took = time.time() - start
    assert path == out / "drem.pt"
    header, _ = load_checkpoint(str(path))
    assert header["env_id"] == task and header["modalities"] == ["fixed", "wrist", "ft"]
    assert header["train"]["iterations"] == 50 and header["sampler"]["num_children"] == 4
    quality = json.loads((out / "quality.json").read_text())
    assert quality["env_id"] == task and quality["seeds"] == [0] and -1 <= quality["value_order_spearman"] <= 1
    assert all((out / PUBLISHED[k]).is_file() for k in PUBLISHED if "image" not in k)
    first = capsys.readouterr().err
    ran = [s for s in LOGGED if "image" not in s]  # the general recipe trains no image twin
    assert "recipe default" in first and "demo: running" in first and all(f"{s}: running" in first for s in ran)

    build_reward(task, scale="tiny", out=out)
    again = capsys.readouterr().err
    assert all(f"{s}: skipped" in again for s in ran) and ": running" not in again
    print(f"tiny build: {took:.0f} s")


def test_the_sampler_reads_the_socket_geometry_only_for_a_phase_that_needs_it():
    from drem_maniskill.pipeline.tree.backward import socket_geometry
    from drem_maniskill.pipeline.tree.config import SamplerConfig

    class Adapter:
        calls = 0

        def socket_geometry(self):
            Adapter.calls += 1
            return "geometry"

    class Sampler:
        adapter = Adapter()

    assert socket_geometry(Sampler(), SamplerConfig()) is None and Adapter.calls == 0
    face = SamplerConfig.from_dict({"phases": {"face": {"depth": 2}}})
    assert socket_geometry(Sampler(), face) == "geometry" and Adapter.calls == 1


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


def test_every_recipe_section_is_read_by_a_declared_stage():
    assert {section for s in STAGES.values() for section in s.sections} == set(SECTIONS)
    assert all(set(s.reads) <= set(STAGES) - {s.name} for s in STAGES.values())


def _fake_stages(monkeypatch, shipped: Path) -> None:
    """Every expensive stage replaced by one writing a few bytes, and ``shipped`` as the shipped rewards' folder."""

    def write(path, text: str = "made") -> None:
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text)

    def examine(task, checkpoint, out, r) -> None:
        write(out, "{}")
        write(out.parent / "examination.png")

    monkeypatch.setattr(build_module, "_sample", lambda expert, out, r, episode=0: write(out))
    monkeypatch.setattr(build_module, "_train", lambda tree, out, *args: write(out, f"model of {out.parent.name}"))
    monkeypatch.setattr(build_module, "_examine", examine)
    monkeypatch.setattr(build_module, "_calibrate", lambda checkpoint, tree, out, r: write(out, "{}"))
    monkeypatch.setattr(build_module, "REWARDS_DIRS", (shipped,))


def _digests(folder: Path) -> dict:
    return {str(p): hashlib.sha256(p.read_bytes()).hexdigest() for p in sorted(folder.rglob("*")) if p.is_file()}


def test_a_full_scale_build_works_in_its_work_folder_and_leaves_the_shipped_rewards_as_they_are(tmp_path, monkeypatch):
    shipped = tmp_path / "rewards"
    (shipped / "PegInHole-v1").mkdir(parents=True)
    (shipped / "PegInHole-v1" / "drem.pt").write_text("shipped")
    checkout = _digests(ROOT / "rewards")
    _fake_stages(monkeypatch, shipped)
    monkeypatch.chdir(tmp_path)
    path = build_reward("PegInHole-v1")
    work = Path("outputs") / "build_reward" / "PegInHole-v1" / "full"
    assert path == work / "drem.pt" and path.read_text() == "model of reward"
    assert all((work / name).is_file() for name in PUBLISHED.values())
    assert _digests(shipped) == {str(shipped / "PegInHole-v1" / "drem.pt"): hashlib.sha256(b"shipped").hexdigest()}
    assert _digests(ROOT / "rewards") == checkout


def test_publish_copies_the_products_into_the_shipped_folder_saying_what_it_replaces(tmp_path, monkeypatch, capsys):
    dest = tmp_path / "rewards" / "PegInHole-v1"
    dest.mkdir(parents=True)
    (dest / "drem.pt").write_text("shipped")
    (dest / "support.json").write_text("{}")
    _fake_stages(monkeypatch, tmp_path / "rewards")
    with pytest.raises(RecipeError, match="only a full-scale build publishes"):
        build_reward("PegInHole-v1", scale="tiny", out=tmp_path / "tiny", publish=True)
    assert not (tmp_path / "tiny").exists()
    path = build_reward("PegInHole-v1", out=tmp_path / "work", publish=True)
    assert path == dest / "drem.pt" and path.read_text() == "model of reward"
    assert sorted(p.name for p in dest.iterdir()) == sorted(PUBLISHED.values())
    err = capsys.readouterr().err
    assert f"publish: {dest / 'drem.pt'} replaced (changed)" in err
    assert f"publish: {dest / 'support.json'} unchanged" in err
    assert f"publish: {dest / 'quality.json'} (new)" in err
    assert (dest / "drem_image.pt").read_text() == "model of reward_image"



@pytest.mark.slow
def test_a_forest_samples_a_tree_per_demo_episode_and_trains_on_all_of_them_and_their_scene_swap_negatives(tmp_path):
    import h5py

    from drem_maniskill.drem.model import ModelConfig
    from drem_maniskill.pipeline.dataset import TreeDataset
    from drem_maniskill.pipeline.recipe import GENERAL_DEFAULTS, merge

    recipe = merge(GENERAL_DEFAULTS, {"demo": {"seed": 1000, "episodes": 2, "trees": 2},
                                      "scene_swap": {"negatives": True, "lag": 4, "max_pairs": 30},
                                      "train": {"model": {"modalities": ["fixed", "poses"]}},
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

    # Scene-swap negatives: written per tree, their pairs more than the lag apart, counted in the header.
    counts = []
    for k in range(2):
        with h5py.File(tmp_path / "scene_swap" / f"negatives_{k}.h5") as f:
            depth, robot_depth = f["depth"][()], f["step"][()]
            assert f["poses"].shape[0] == len(depth) == 30 and (depth - robot_depth > 4).all()
            counts.append(len(depth))
    assert header["negatives"] == dict(files=["negatives_0.h5", "negatives_1.h5"], nodes=sum(counts))
    assert header["modalities"] == ["fixed", "poses"] and header["model"]["poses_size"] > 0


def test_a_forest_needs_as_many_demo_episodes_as_trees():
    with pytest.raises(RecipeError, match=r"trees = 3 needs 1 <= trees <= episodes \(= 2\)"):
        load_recipe("PushCube-v1", recipe={"demo": {"episodes": 2, "trees": 3}})


def test_a_second_build_in_a_busy_work_folder_fails_naming_the_first(tmp_path):
    import subprocess
    import sys

    holder = subprocess.Popen(
        [sys.executable, "-c", "import time; from drem_maniskill.utils.lock import folder_lock\n"
                               f"with folder_lock({str(tmp_path)!r}, 0, 'built', '', 'test'):\n"
                               "    print('held', flush=True); time.sleep(60)"],
        stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout.readline().strip() == "held"
        with pytest.raises(RuntimeError, match=f"being built by another process \\(pid {holder.pid}\\)"):
            build_reward("PegInHole-v1", scale="tiny", out=tmp_path)
        assert not (tmp_path / "recipe.json").exists()  # nothing written beside the first build
    finally:
        holder.kill()
        holder.wait()
