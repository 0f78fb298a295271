"""The scene swap: the measure at the expert's end, and negatives with the robot ahead of the objects."""

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


def test_negatives_take_one_depth_label_or_one_per_row(tmp_path):
    import torch

    from drem_maniskill.pipeline.policy_rounds import write_negatives

    rows = [({"fixed": torch.zeros(1, 8, 8, 3, dtype=torch.uint8)}, 0.5, 7, t) for t in range(3)]
    write_negatives(tmp_path / "one.h5", rows, 9, ["fixed"], False)
    write_negatives(tmp_path / "each.h5", rows, np.array([5, 6, 7]), ["fixed"], False)
    with h5py.File(tmp_path / "one.h5") as one, h5py.File(tmp_path / "each.h5") as each:
        assert one["depth"][()].tolist() == [9, 9, 9] and each["depth"][()].tolist() == [5, 6, 7]


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


def test_swap_ratios_are_the_swapped_scenes_mean_over_the_ends_mean():
    from drem_maniskill.pipeline.scene_swap import swap_ratios

    rows = [dict(end=1.0, robot_at_end=0.9, objects_at_end=0.1), dict(end=0.6, robot_at_end=0.7, objects_at_end=0.3)]
    assert swap_ratios(rows) == pytest.approx(dict(robot_only_over_expert=1.0, objects_only_over_expert=0.25))
    assert swap_ratios([]) == dict(robot_only_over_expert=None, objects_only_over_expert=None)


@pytest.mark.slow
def test_scene_swap_pays_the_experts_end_as_the_episode_did_and_moves_only_what_it_says(tmp_path):
    """On PushCube-v1: the end is paid what the episode's last step was, and the swapped scenes put the cube back
    (robot at the end) or the hand back (cube at the end)."""
    import torch

    from drem_maniskill.pipeline.examine import _make_env, examination_episode
    from drem_maniskill.pipeline.scene_swap import scene_swap
    from tests.conftest import tiny_checkpoint

    checkpoint = tiny_checkpoint(tmp_path / "drem.pt", "PushCube-v1", ("fixed",), ("base_camera",))
    env = _make_env("PushCube-v1", checkpoint, None)
    u = env.unwrapped
    try:
        env.reset(seed=0)
        cube_start, tcp_start = u.obj.pose.p.clone(), u.agent.tcp.pose.p.clone()
        ep = examination_episode(env, "expert", 0)
        assert ep["success"]
        cube_end, tcp_end = u.obj.pose.p.clone(), u.agent.tcp.pose.p.clone()
        assert torch.linalg.norm(cube_end - cube_start) > 0.05 and torch.linalg.norm(tcp_end - tcp_start) > 0.05
        swap = scene_swap(env, 0)
        assert swap["end"] == pytest.approx(ep["rewards"][-1], abs=1e-5)
        assert len({round(swap[k], 4) for k in ("end", "robot_at_end", "objects_at_end")}) == 3
        # The last scene paid: the cube where the expert left it, the hand back where it started.
        assert torch.allclose(u.obj.pose.p, cube_end, atol=1e-4)
        assert torch.allclose(u.agent.tcp.pose.p, tcp_start, atol=1e-4)
    finally:
        env.close()
