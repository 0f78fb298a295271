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


def test_a_stall_round_takes_a_finished_sac_run_as_its_policy_only_when_the_round_would_train_that_run(tmp_path):
    """place_policy: the general build's state SAC run (other folder, evaluations and env process) becomes round k's
    policy under the round's config; a run of another preset setting is refused, and round k's folder follows k - 1."""
    import stall_round

    from drem_maniskill.pipeline.policy_rounds import RoundsConfig
    from drem_maniskill.rl.config import RLConfig

    rounds = RoundsConfig(**stall_round.stall_rounds(2)["rounds"])
    run = tmp_path / "runs" / "seed0"
    run.mkdir(parents=True)
    RLConfig.from_preset("state", task="PegInHole-v1", reward="drem", seed=0, steps=50_000, out=str(run),
                         reward_checkpoint="elsewhere/drem.pt", overlap_env=False).save(run / "config.json")
    (run / "eval.csv").write_text("steps,success_rate\n50000,0.0\n")
    stall_round.place_policy("PegInHole-v1", tmp_path / "work", run, rounds, 2)
    placed = RLConfig.load(tmp_path / "work" / "rounds" / "round_2" / "sac" / "config.json")
    assert placed.seed == 1 and placed.eval_every == 50_000 and placed.out.endswith("round_2/sac")
    assert placed.reward_checkpoint.endswith("rounds/round_1/train/drem.pt")
    assert (tmp_path / "work" / "rounds" / "round_2" / "sac" / "eval.csv").is_file()

    RLConfig.from_preset("state", task="PegInHole-v1", reward="drem", seed=0, steps=50_000, out=str(run),
                         learning_rate=1e-3).save(run / "config.json")
    with pytest.raises(ValueError, match=r"not the SAC run round 1 trains: it differs in \['learning_rate'\]"):
        stall_round.place_policy("PegInHole-v1", tmp_path / "other", run, rounds, 1)

    out = Path("outputs/general")
    assert stall_round.folders(out, "T", 1) == (out / "stall" / "T", out / "build" / "T", out / "T" / "drem")
    assert stall_round.folders(out, "T", 2) == (out / "stall2" / "T", out / "stall" / "T", out / "stall" / "T" / "sac")


def test_a_variant_built_on_another_takes_its_demo_tree_reward_and_finished_rounds_but_not_the_rounds_mark(tmp_path):
    """reuse_trees: a variant that adds a round starts from the rounds its source finished; ``rounds/drem.pt``, which
    marks the rounds stage done, stays behind, or the added round would be skipped."""
    import general_recipe

    source = tmp_path / "source"
    for name in ("expert/expert.h5", "reward/drem.pt", "rounds/round_1/collected.json", "rounds/round_1/train/drem.pt",
                 "rounds/drem.pt", "tree.h5"):
        (source / name).parent.mkdir(parents=True, exist_ok=True)
        (source / name).write_text(name)

    def files(folder: Path) -> list:
        return sorted(str(p.relative_to(folder)) for p in folder.rglob("*") if p.is_file())

    general_recipe.reuse_trees(tmp_path / "with_reward", source, True)
    assert files(tmp_path / "with_reward") == ["expert/expert.h5", "reward/drem.pt", "rounds/round_1/collected.json",
                                               "rounds/round_1/train/drem.pt", "tree.h5"]
    general_recipe.reuse_trees(tmp_path / "trees_only", source, False, grow=True)
    assert files(tmp_path / "trees_only") == ["expert/expert.h5", "tree.h5.partial"]
