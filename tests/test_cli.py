"""The command line end to end at a tiny scale, as a user runs it (subprocesses)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import h5py
import pytest


def run(*args, cwd=None) -> str:
    """Run ``drem-maniskill ARGS`` with this interpreter; fail with its output."""
    proc = subprocess.run([sys.executable, "-m", "drem_maniskill.cli", *args], capture_output=True, text=True, cwd=cwd,
                          timeout=900)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    return proc.stdout


def test_help_of_every_subcommand(capsys):
    """The console script answers --help; each subcommand's help, in this process (an import costs seconds)."""
    from drem_maniskill.cli import main

    assert "usage: drem-maniskill" in run("--help")
    for cmd in ("demo", "record-expert", "scripted-success", "examine", "sample", "train-reward", "build-reward",
                "calibrate-support", "train-policy", "sweep"):
        with pytest.raises(SystemExit) as done:
            main([cmd, "--help"])
        assert done.value.code == 0 and "usage: drem-maniskill " + cmd in capsys.readouterr().out


def test_the_rl_commands_are_subcommands_of_the_one_command_line():
    import runpy

    import drem_maniskill.rl
    from drem_maniskill.cli import build_parser

    commands = next(a for a in build_parser()._actions if a.dest == "command").choices
    assert {"train-policy", "sweep", "compare"} <= set(commands)
    with pytest.raises(SystemExit, match="drem-maniskill train-policy"):  # python -m drem_maniskill.rl
        runpy.run_path(str(Path(drem_maniskill.rl.__file__).parent / "__main__.py"), run_name="__main__")


def _options(command: str) -> set:
    """The option strings of one subcommand of ``drem-maniskill``."""
    from drem_maniskill.cli import build_parser

    parser = build_parser()
    sub = next(a for a in parser._actions if a.dest == "command").choices[command]
    return {o for a in sub._actions for o in a.option_strings}


def _flags_of(cls, prefix: str = "") -> set:
    """``--field-name`` of every field of dataclass ``cls``, nested dataclasses as ``--outer-inner``."""
    import dataclasses
    import typing

    hints = typing.get_type_hints(cls)
    flags = set()
    for f in dataclasses.fields(cls):
        flag = prefix + f.name.replace("_", "-")
        hint = hints[f.name]
        flags |= _flags_of(hint, flag + "-") if dataclasses.is_dataclass(hint) else {"--" + flag}
    return flags


def test_every_config_field_has_a_flag():
    """A field added to a config gets its flag: the CLI derives them, and this names any it misses."""
    import dataclasses

    from drem_maniskill.pipeline import SamplerConfig
    from drem_maniskill.pipeline.train_reward import TrainConfig
    from drem_maniskill.rl.config import RLConfig

    sample = _options("sample")
    missing = _flags_of(SamplerConfig) - sample - {"--phases"}
    assert not missing, f"sample lacks {sorted(missing)}"
    if "phases" in {f.name for f in dataclasses.fields(SamplerConfig)}:
        from drem_maniskill.pipeline.tree.phases import PHASES

        assert "--phase" in sample
        for name, phase in PHASES.items():
            for f in dataclasses.fields(phase.config):
                assert f"--{name}-{f.name}".replace("_", "-") in sample
    missing = _flags_of(TrainConfig) - _options("train-reward")
    assert not missing, f"train-reward lacks {sorted(missing)}"
    missing = _flags_of(RLConfig) - _options("train-policy")
    assert missing == set(), f"train-policy lacks {sorted(missing)}"  # --preset: the preset's own flag
    # Names that differ from the field's, kept for existing command lines.
    assert {"--pairs", "--modalities", "--image-size"} <= _options("train-reward")
    assert {"--bf16", "--no-bf16", "--preset"} <= _options("train-policy")


def _captured(monkeypatch, module: str, name: str) -> list:
    """Replace ``module.name`` by a function that records its arguments and stops the command."""
    import importlib

    calls = []

    def fake(*args, **kwargs):
        calls.append((args, kwargs))
        raise ValueError("captured")

    monkeypatch.setattr(importlib.import_module(module), name, fake)
    return calls


def test_sample_flags_reach_the_sampler_config(monkeypatch, capsys):
    from drem_maniskill.cli import main

    calls = _captured(monkeypatch, "drem_maniskill.pipeline", "backward_sample")
    argv = ["sample", "--expert", "x.h5", "--preset", "tiny", "--num-children", "7", "--no-randomize-colors",
            "--face-depth", "3", "--goal-presses-count", "11", "--phase", "turn.tilt=5", "--phase", "face.step=0.002",
            "--turn-depth", "2"]
    assert main(argv) == 2 and "captured" in capsys.readouterr().err
    config = calls[0][0][2]
    assert (config.num_children, config.max_depth, config.randomize_colors) == (7, 40, False)
    if hasattr(config, "phases"):
        assert config.phases["face"].depth == 3 and config.phases["face"].step == 0.002
        assert config.phases["goal_presses"].count == 11
        assert config.phases["turn"].depth == 2 and config.phases["turn"].tilt == 5.0


def test_train_reward_flags_reach_the_train_config(monkeypatch, capsys):
    from drem_maniskill.cli import main

    calls = _captured(monkeypatch, "drem_maniskill.pipeline.train_reward", "train_reward")
    monkeypatch.setattr("drem_maniskill.pipeline.dataset.dataset_modalities", lambda path: ("fixed", "wrist"))
    assert main(["train-reward", "--dataset", "t.h5", "--preset", "tiny", "--pairs", "5", "--lr", "0.001"]) == 2
    config = calls[0][0][2]
    assert (config.iterations, config.pairs_per_batch, config.lr) == (20, 5, 0.001)
    assert config.model.modalities == ("fixed", "wrist") and config.model.image_size == 64
    assert main(["train-reward", "--dataset", "t.h5", "--modalities", "fixed", "--model-image-size", "128"]) == 2
    config = calls[1][0][2]
    assert config.model.modalities == ("fixed",) and config.model.image_size == 128 and config.iterations == 20_000


def test_train_policy_flags_reach_the_rl_config(monkeypatch, capsys):
    from drem_maniskill.cli import main

    calls = _captured(monkeypatch, "drem_maniskill.rl.train_policy", "train_policy")
    argv = ["train-policy", "--preset", "state", "--steps", "8", "--net-arch", "64", "64", "--obs-norm",
            "--no-bf16", "--reward", "engineered", "--env-kwargs", '{"sim_backend": "cpu"}']
    assert main(argv) == 2
    config = calls[0][0][0]
    assert (config.preset, config.steps, config.net_arch, config.obs_norm) == ("state", 8, (64, 64), ())
    assert config.train_bf16 is False and config.reward == "engineered" and config.env_kwargs == {"sim_backend": "cpu"}
    assert config.batch_size == 256  # the state preset's, untouched


@pytest.mark.parametrize("argv, message", [
    (["sample", "--expert", "x.h5", "--preset", "huge"], "unknown sampler preset 'huge'; choose one of"),
    (["train-reward", "--dataset", "t.h5", "--preset", "huge"], "unknown training preset 'huge'; choose one of"),
    (["train-policy", "--preset", "huge"], "unknown preset 'huge'; choose one of ['state', 'light', 'image', 'paper']"),
    (["sample", "--expert", "x.h5", "--phase", "face.depth=many"], "cannot read 'many' as int"),
    (["sample", "--expert", "x.h5", "--phase", "nowhere.depth=1"], "unknown name 'nowhere'; choose one of"),
    (["sample", "--expert", "x.h5", "--phase", "face=1"], "--phase takes NAME.FIELD=VALUE"),
])
def test_a_bad_preset_or_value_is_one_clear_error_line(argv, message, capsys, monkeypatch):
    from drem_maniskill.cli import main

    monkeypatch.setattr("drem_maniskill.pipeline.dataset.dataset_modalities", lambda path: ("fixed",))
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"drem-maniskill {argv[0]}: error: ") and message in err and err.count("\n") == 1


def test_a_value_of_the_wrong_type_is_refused_by_argparse(capsys):
    from drem_maniskill.cli import main

    with pytest.raises(SystemExit) as exit_:
        main(["sample", "--expert", "x.h5", "--num-children", "many"])
    assert exit_.value.code == 2 and "--num-children: invalid int value: 'many'" in capsys.readouterr().err


def test_build_reward_calls_the_pipeline(monkeypatch, capsys, tmp_path):
    import types

    from drem_maniskill.cli import main

    with pytest.raises(SystemExit) as exit_:
        main(["build-reward", "--help"])
    assert exit_.value.code == 0 and "--scale {tiny,demo,full}" in capsys.readouterr().out
    calls = []
    fake = types.ModuleType("drem_maniskill.pipeline.build_reward")
    fake.build_reward = lambda task, **kwargs: calls.append((task, kwargs)) or tmp_path / "drem.pt"
    monkeypatch.setitem(sys.modules, "drem_maniskill.pipeline.build_reward", fake)
    assert main(["build-reward", "--task", "PegInHole-v1", "--scale", "tiny", "--out", str(tmp_path)]) == 0
    assert calls == [("PegInHole-v1", dict(scale="tiny", out=str(tmp_path), recipe=None, publish=False))]
    assert f"reward: {tmp_path / 'drem.pt'}" in capsys.readouterr().out
    assert main(["build-reward", "--task", "PegInHole-v1", "--publish"]) == 0
    assert calls[1] == ("PegInHole-v1", dict(scale="full", out=None, recipe=None, publish=True))


def test_a_missing_checkpoint_error_names_the_fix(tmp_path):
    """Every route to a checkpoint goes through ``resolve_checkpoint``: one message, naming the commands."""
    from drem_maniskill.drem.checkpoint import resolve_checkpoint
    from drem_maniskill.rl.rewards import REWARDS

    missing = str(tmp_path / "none.pt")
    for call in (lambda: resolve_checkpoint("PegInHole-v1", missing),
                 lambda: REWARDS["drem"].make("PegInHole-v1", {"drem_checkpoint": missing})):
        with pytest.raises(FileNotFoundError) as err:
            call()
        assert str(err.value).startswith(f"DREM checkpoint {missing} not found. Build one with "
                                         "`drem-maniskill build-reward --task PegInHole-v1`")
        assert "drem_checkpoint=PATH" in str(err.value) and "--reward-checkpoint PATH" in str(err.value)


@pytest.mark.slow
def test_chain_record_sample_train_examine(tmp_path, capsys):
    """The commands one after another, in this process (the console script itself: test_help_of_every_subcommand)."""
    from drem_maniskill.cli import main

    def here(*args) -> str:
        assert main(list(args)) == 0
        return capsys.readouterr().out

    here("record-expert", "--task", "USBInsertion-v1", "--seed", "1000", "--out", str(tmp_path / "expert"))
    expert = tmp_path / "expert" / "expert.h5"
    assert json.loads((tmp_path / "expert" / "expert.json").read_text())["env_info"]["env_id"] == "USBInsertion-v1"
    out = here("sample", "--expert", str(expert), "--out", str(tmp_path / "tree.h5"), "--preset", "tiny")
    assert "progress tree:" in out
    with h5py.File(tmp_path / "tree.h5", "r") as f:
        assert f["in_start_region"][()].any()
    out = here("train-reward", "--dataset", str(tmp_path / "tree.h5"), "--out", str(tmp_path / "reward"),
              "--preset", "tiny")
    assert (tmp_path / "reward" / "drem.pt").exists()
    out = here("examine", "--task", "USBInsertion-v1", "--checkpoint", str(tmp_path / "reward" / "drem.pt"),
              "--out", str(tmp_path / "exam"), "--episodes", "1")
    quality = json.loads((tmp_path / "exam" / "quality.json").read_text())
    assert set(quality["curves"]) == {"direct_success", "align_success", "search_fail", "random"}
    assert quality["success_rate"]["direct_success"] == 1.0
    assert -1 <= quality["spearman_with_normalized_dense"] <= 1 and -1 <= quality["spearman_with_insertion_depth"] <= 1
    assert len(quality["dense_curves"]["random"][0]) == len(quality["curves"]["random"][0])
    from drem_maniskill.evaluate.probes import (
        FACE_PUSHED, HOLD_POSITIONS, SIDE_POSITION, SIDE_PUSHED, TURNED_HOVER, UPRIGHT_HOVER,
    )

    held = quality["held_positions"]
    floor = "pressed on the floor, 75 mm beside"
    assert list(held) == [*HOLD_POSITIONS, floor, SIDE_POSITION, SIDE_PUSHED, FACE_PUSHED, TURNED_HOVER, UPRIGHT_HOVER,
                          "inserted"]
    assert quality["turned_over_upright"] == pytest.approx(held[TURNED_HOVER]["mean"] / held[UPRIGHT_HOVER]["mean"])
    assert quality["turned_over_inserted"] == pytest.approx(held[TURNED_HOVER]["mean"] / held["inserted"]["mean"])
    assert all(v["reached_error_mm"] < 2.0 for k, v in held.items()
               if k not in ("inserted", SIDE_PUSHED) and "beside" not in k)
    # Pressed on the floor: 2 mm short of the target below it, nowhere else.
    assert 1.0 < held[floor]["reached_error_mm"] < 3.0
    assert quality["floor_beside_over_inserted"] == pytest.approx(held[floor]["mean"] / held["inserted"]["mean"])
    assert held[SIDE_POSITION]["reached_error_mm"] < 0.5  # beside the block's side, clear of it
    assert quality["side_over_inserted"] == pytest.approx(held[SIDE_POSITION]["mean"] / held["inserted"]["mean"])
    # Pushed into the block's side and down: the plug's overmould stops on the block's edge, 8 mm above the target.
    assert 7.0 < held[SIDE_PUSHED]["reached_error_mm"] < 9.0
    assert quality["side_pushed_over_inserted"] == pytest.approx(held[SIDE_PUSHED]["mean"] / held["inserted"]["mean"])
    assert 8.0 < held[FACE_PUSHED]["reached_error_mm"] < 11.0  # on the face, 8 mm above its target and slid out
    assert quality["face_pushed_over_inserted"] == pytest.approx(held[FACE_PUSHED]["mean"] / held["inserted"]["mean"])
    assert quality["face_over_hover"] == pytest.approx(held["pressed 3 mm beside"]["mean"]
                                                       / held["4 mm above, 4 mm off"]["mean"])
    assert quality["colour_spread"]["max_std"] == max(v["std"] for k, v in held.items() if k != "inserted")
    plateau_keys = {"episodes", "mean_reward", "direct_success_final", "fraction"}
    assert plateau_keys <= set(quality["contact_plateau"])
    assert set(quality["contact_plateau"]) - plateau_keys <= {"on_face", "at_opening"}
    assert (tmp_path / "exam" / "examination.png").stat().st_size > 10_000


@pytest.mark.parametrize("argv", [
    ["train-policy", "--task", "NoSuchTask-v1", "--steps", "8"],
    ["record-expert", "--task", "NoSuchTask-v1"],
    ["scripted-success", "--task", "NoSuchTask-v1"],
    ["examine", "--task", "NoSuchTask-v1", "--checkpoint", "none.pt"],
    ["demo", "--tasks", "PegInHole-v1", "NoSuchTask-v1"],
])
def test_an_unknown_task_id_is_one_error_line_listing_the_ids(argv, capsys, tmp_path, monkeypatch):
    from drem_maniskill.cli import main

    monkeypatch.chdir(tmp_path)  # nothing may be written, but if it were, not into the checkout
    assert main(argv) == 2
    err = capsys.readouterr().err
    from drem_maniskill.envs import DREM_ALIASES, TASKS

    ours = ", ".join([*TASKS, *DREM_ALIASES])
    assert "PegInHole-v1, USBInsertion-v1, SquarePegInHole-v1" in ours and "PegInHole-DREM-v1" in ours
    assert err.startswith(f"drem-maniskill {argv[0]}: error: unknown task id 'NoSuchTask-v1'. "
                          f"Ours: {ours}; ManiSkill's: ")
    assert "PegInsertionSide-v1" in err and "Traceback" not in err and err.count("\n") == 1
    assert not list(tmp_path.iterdir())


def test_a_misspelt_task_id_gets_a_suggestion(capsys):
    from drem_maniskill.cli import main

    assert main(["train-policy", "--task", "PegInHoel-v1"]) == 2
    assert "Did you mean PegInHole-v1" in capsys.readouterr().err
