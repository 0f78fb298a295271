"""``SamplerConfig``: its dict form reads back, unknown keys are refused, a phase registers in one place."""

from __future__ import annotations

import json
from dataclasses import dataclass

import h5py
import numpy as np
import pytest

from drem_maniskill.pipeline.recipe import load_recipe
from drem_maniskill.pipeline.tree import tree_file
from drem_maniskill.pipeline.tree.config import SamplerConfig
from drem_maniskill.pipeline.tree.phases import FIRST_STREAM, PHASES, Phase, register_phase, stream_of


NESTED_USB = {
    "num_children": 500, "expert_step_scale": 4.0, "workers": 2, "max_depth": 80,
    "phases": {
        "outward": {"depth": 10, "lineages": 12, "children": 100, "elevations": [0.0, -35.0, -60.0]},
        "face": {"depth": 8, "lineages": 8, "children": 60, "step": 0.0015, "elevation": -30.0},
        "side": {"depth": 8, "children": 60, "step": 0.004, "elevation": -60.0},
        "push": {"children": 30},
        "turn": {"depth": 24, "lineages": 2, "children": 16, "tilt": 20.0},
        "goal_presses": {"count": 500},
    },
}


def test_the_dict_form_reads_back_to_the_same_config():
    config = SamplerConfig.from_dict(NESTED_USB)
    assert list(config.phases_on()) == ["outward", "face", "side", "push", "goal_presses", "turn"]
    # to_dict is the nested form, JSON-ready, and reads back to the same config.
    nested = json.loads(json.dumps(config.to_dict()))
    assert SamplerConfig.from_dict(nested) == config and nested["phases"]["turn"]["children"] == 16
    assert nested["phases"]["outward"]["elevations"] == [0.0, -35.0, -60.0]
    # The shipped rewards' recipes: the USB one is this config on one worker; the peg's has the outward phase alone.
    assert load_recipe("USBInsertion-v1").sampler_config() == SamplerConfig.from_dict({**NESTED_USB, "workers": 1})
    peg = load_recipe("PegInHole-v1").sampler_config()
    assert list(peg.phases_on()) == ["outward"] and peg.phases["outward"].depth == 10


def test_presets_and_overrides_give_the_nested_config():
    tiny = SamplerConfig.preset("tiny", phases=dict(face=dict(depth=2, lineages=4), goal_presses=dict(count=8)))
    assert tiny == SamplerConfig.from_dict(dict(num_children=4, max_depth=40, phases=dict(
        face=dict(depth=2, lineages=4), goal_presses=dict(count=8))))
    assert tiny.phases["face"].children == 60 and tiny.phases["side"].depth == 0
    assert SamplerConfig() == SamplerConfig.preset("paper") and not SamplerConfig().phases_on()
    # Every phase is there, off at size 0; an off phase's other settings are its defaults (they change nothing).
    assert set(SamplerConfig().phases) == set(PHASES)
    assert SamplerConfig.from_dict(dict(phases=dict(face=dict(depth=0, children=24)))) == SamplerConfig()
    with pytest.raises(ValueError, match="unknown sampler preset 'huge'"):
        SamplerConfig.preset("huge")


@pytest.mark.parametrize("bad, named", [
    (dict(face_deepth=8), "face_deepth"),
    (dict(wiggle=1), "wiggle"),
    (dict(phases=dict(face=dict(dpeth=8))), "dpeth"),
    (dict(phases=dict(wiggle=dict(depth=1))), "wiggle"),
])
def test_unknown_keys_are_refused_by_name_with_the_valid_ones(bad, named):
    with pytest.raises(ValueError, match=named) as err:
        SamplerConfig.from_dict(bad)
    assert "valid ones" in str(err.value)


def test_a_phase_setting_outside_phases_is_refused_naming_where_it_goes():
    with pytest.raises(ValueError, match=r"unknown sampler setting 'face_depth'.*phases\.face\.depth"):
        SamplerConfig.from_dict(dict(face_depth=8))


@dataclass
class NudgeConfig:
    """Settings of a test phase: random actions from the goal, labelled one step from it."""

    count: int = 0
    """Random actions from the goal state (0: off)."""
    scale: float = 0.1
    """Their arm action range."""


def sample_nudges(ctx, config: NudgeConfig) -> None:
    """One group, ``nudge``, of children of the goal labelled depth 1; its counter makes a resume skip it."""
    if tree_file.completed(ctx.partial, "nudge_completed"):
        return
    with h5py.File(ctx.partial, "r") as f:
        seeds, nodes = tree_file.read_seeds(f["seeds/depth_0"])
    merged = ctx.children_of(seeds, nodes, 0, config.count, config.scale)
    tree_file.append_depth(ctx.partial, merged, 1, np.zeros(0, np.int64), group="nudge", counter="nudge_completed",
                           count=1)


@pytest.fixture
def nudge_phase():
    """A phase registered in one place (its settings, its sampler, its record), unregistered after the test."""
    phase = register_phase(Phase(name="nudge", config=NudgeConfig, sample=sample_nudges, size="count",
                                 counter="nudge_completed", growable=True, labels="1: a step from the goal"))
    yield phase
    PHASES.pop("nudge")


def test_a_registered_phase_is_in_the_config_and_draws_its_own_stream(nudge_phase):
    assert list(PHASES)[-1] == "nudge" and stream_of("nudge") == FIRST_STREAM + len(PHASES) - 1
    assert len({stream_of(n) for n in PHASES}) == len(PHASES)
    assert SamplerConfig().phases["nudge"] == NudgeConfig() and "nudge" not in SamplerConfig().phases_on()
    config = SamplerConfig.from_dict(dict(phases=dict(nudge=dict(count=3))))
    assert config == SamplerConfig.preset("paper", phases=dict(nudge=dict(count=3)))
    assert config.to_dict()["phases"]["nudge"] == dict(count=3, scale=0.1)
    assert SamplerConfig.from_dict(config.to_dict()) == config
    with pytest.raises(ValueError, match="registered already"):
        register_phase(nudge_phase)


@pytest.mark.slow
def test_a_registered_phase_runs_in_backward_sample_and_a_finished_tree_gains_it(pipeline, tmp_path, nudge_phase):
    from drem_maniskill.pipeline.tree.backward import backward_sample

    out = tmp_path / "tree.h5"
    tree_file.partial_path(out).write_bytes(open(pipeline["tree"], "rb").read())
    with h5py.File(pipeline["tree"], "r") as f:
        n = len(f["depth"])
    config = SamplerConfig.preset("tiny", phases=dict(nudge=dict(count=3)))
    backward_sample(pipeline["expert"], str(out), config, progress=False)
    with h5py.File(out, "r") as f:
        assert f.attrs["complete"] and int(f.attrs["nudge_completed"]) == 1 and len(f["depth"]) == n + 3
        assert np.all(f["depth"][n:] == 1) and np.all(f["parent"][n:] == 0) and not f["is_seed"][n:].any()
        assert json.loads(f.attrs["header"])["config"]["phases"]["nudge"] == dict(count=3, scale=0.1)
        moved = np.linalg.norm(f["tcp_pose"][n:, :3] - f["tcp_pose"][0, :3], axis=1)
    assert np.all(moved > 0) and np.all(moved < 0.01)  # small moves: a tenth of the 2 cm full step


def test_default_depth_limit_follows_the_demo():
    # The measure walks back one demo step per depth: a 90-step demo (a PlugCharger-v1 episode) needs more than 80.
    assert SamplerConfig().depth_limit(90) == 180 and SamplerConfig().depth_limit(16) == 80
    assert SamplerConfig(max_depth=60).depth_limit(90) == 60
    with pytest.raises(ValueError, match="max_depth must be >= 0"):
        SamplerConfig(max_depth=-1)
