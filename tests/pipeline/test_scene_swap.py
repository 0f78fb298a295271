"""Scene-swap negatives: the demo's robot ahead of its objects, labelled with the objects' depth."""

import h5py
import numpy as np
import pytest


def test_swap_pairs_put_the_robot_more_than_lag_steps_ahead_and_spread_a_cap_evenly():
    from drem_maniskill.pipeline.scene_swap import swap_pairs

    pairs = swap_pairs(range(8), lag=4)
    assert pairs == [(0, 5), (0, 6), (0, 7), (1, 6), (1, 7), (2, 7)]
    capped = swap_pairs(range(30), lag=4, max_pairs=10)
    assert len(capped) == 10 and capped[0] == (0, 5) and capped[-1] == (24, 29)
    assert swap_pairs(range(5), lag=4) == []


@pytest.mark.slow
def test_scene_swaps_of_a_pushcube_demo_show_the_hand_ahead_of_the_cube(tmp_path):
    """Each negative is the demo's robot at depth k over its cube at depth j > k + lag, labelled j; the push's end
    with the cube back at its start is neither the start nor the end the demo recorded."""
    from drem_maniskill.experts.recording import record_expert
    from drem_maniskill.pipeline.scene_swap import swap_negatives
    from drem_maniskill.pipeline.tree.expert import load_expert

    rec = record_expert("PushCube-v1", str(tmp_path / "expert"), seeds=[1000])
    demo = load_expert(rec.h5_path)
    result = swap_negatives(rec.h5_path, str(tmp_path / "negatives.h5"), lag=4, progress=False)
    last = demo.length - 1
    assert result == dict(episode=0, negatives=sum(max(0, last - k - 4) for k in range(last + 1)), lag=4,
                          demo_steps=last)
    with h5py.File(tmp_path / "negatives.h5") as f:
        depth, robot_depth, images = f["depth"][()], f["step"][()], f["fixed_rgb"][()]
    assert (depth - robot_depth > 4).all() and depth.max() == last and robot_depth.min() == 0
    swapped = images[(robot_depth == 0) & (depth == last)][0].astype(float)
    for recorded in (demo.first_obs["fixed_rgb"], demo.last_obs["fixed_rgb"]):
        changed = (np.abs(swapped - np.asarray(recorded, float)).max(axis=-1) > 30).sum()
        assert changed >= 10  # pixels: from the end, only the 4 cm cube moves


def test_a_composed_scene_takes_the_robot_from_one_state_and_every_other_body_from_the_other():
    from drem_maniskill.envs.adapter import DRIVE_KEY, compose_scene

    def state(tag):
        return dict(actors=dict(cube=f"cube {tag}", goal=f"goal {tag}"),
                    articulations=dict(panda=f"panda {tag}", drawer=f"drawer {tag}"),
                    controller=f"controller {tag}", task=f"ft {tag}", **{DRIVE_KEY: f"targets {tag}"})

    scene = compose_scene(state("end"), state("start"), "panda")
    assert scene == dict(actors=dict(cube="cube start", goal="goal start"),
                         articulations=dict(panda="panda end", drawer="drawer start"),
                         controller="controller end", task="ft end", **{DRIVE_KEY: "targets end"})
    bare = compose_scene(dict(articulations=dict(panda=1)), dict(actors=dict(cube=2), articulations={}), "panda")
    assert bare == dict(actors=dict(cube=2), articulations=dict(panda=1))
