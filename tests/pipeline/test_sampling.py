"""Backward sampling into a task progress tree: structure, clear failure and resume, the shipped demos."""

from __future__ import annotations

import json
from pathlib import Path

import gymnasium as gym
import h5py
import numpy as np
import pytest

from drem_maniskill.envs import TASKS, PegInHoleEnv
from drem_maniskill.experts.scripted import HoldPolicy
from drem_maniskill.evaluate.probes import HOLD_POSITIONS
from drem_maniskill.envs.adapter import SocketGeometry
from drem_maniskill.pipeline.tree import tree_file
from drem_maniskill.pipeline.tree.backward import NoStartRegionError, backward_sample
from drem_maniskill.pipeline.tree.child_sampler import ChildSampler
from drem_maniskill.pipeline.tree.config import SamplerConfig
from drem_maniskill.pipeline.tree.phases.face import face_directions
from drem_maniskill.pipeline.tree.phases.outward import outward_directions
from drem_maniskill.pipeline.tree.tree_file import face_entry_depth

GEOMETRY = SocketGeometry.of_task(PegInHoleEnv)
in_opening = GEOMETRY.in_opening
FACE_ENTRY_HEIGHT, FACE_SEED_HEIGHT = GEOMETRY.inserted_height, GEOMETRY.face_seed_height


def _unrendered(**settings) -> SamplerConfig:
    """The tiny preset sampled without rendering its nodes: a tree's nodes, depths and poses are those of the same
    tree rendered (tests/pipeline/test_poses.py), for a fraction of the machine time."""
    return SamplerConfig.preset("tiny", images=False, **settings)


@pytest.mark.slow
def test_progress_tree_structure(pipeline):
    with h5py.File(pipeline["tree"], "r") as f:
        depth, parent = f["depth"][()], f["parent"][()]
        assert f.attrs["complete"]
        n = len(depth)
        assert f["fixed_rgb"].shape == (n, 128, 128, 3) and f["fixed_rgb"].dtype == np.uint8
        assert f["ft"].shape == (n, 8, 6) and f["ft"].dtype == np.float32
        assert f["tcp_pose"].shape == (n, 7)
        assert depth[0] == 0 and parent[0] == -1
        # Every child hangs under a seed of the previous depth.
        assert np.all(parent[1:] < np.arange(1, n))
        assert np.all(depth[parent[1:]] == depth[1:] - 1)
        assert np.all(f["is_seed"][()][parent[1:]])
        # M children per seed, one seed per depth (N = 1).
        counts = np.bincount(depth)
        assert np.all(counts[1:] == SamplerConfig.preset("tiny").num_children)
        # It stopped because the last seed reached the start region.
        last_seed = np.nonzero(f["is_seed"][()])[0][-1]
        assert f["in_start_region"][last_seed] and depth[last_seed] == depth.max()
        assert not f["in_start_region"][0]


@pytest.mark.slow
def _count_depths(monkeypatch) -> list:
    """Record the depth of every ``append_depth`` call from now on (what a resumed run samples again)."""
    calls, real = [], tree_file.append_depth

    def counted(path, data, depth, chosen, **kwargs):
        calls.append(kwargs.get("group") or depth)
        return real(path, data, depth, chosen, **kwargs)

    monkeypatch.setattr(tree_file, "append_depth", counted)
    return calls


def _interrupt_then_resume(expert: str, out, config: SamplerConfig, monkeypatch, stop_at) -> list:
    """Sample until ``stop_at(path, depth, chosen, kwargs)`` says so (KeyboardInterrupt), then resume; the resume's
    ``_count_depths``."""
    real_append = tree_file.append_depth

    def interrupted(path, data, depth, chosen, **kwargs):
        if stop_at(path, depth, chosen, kwargs):
            raise KeyboardInterrupt
        return real_append(path, data, depth, chosen, **kwargs)

    monkeypatch.setattr(tree_file, "append_depth", interrupted)
    with pytest.raises(KeyboardInterrupt):
        backward_sample(expert, str(out), config, progress=False)
    monkeypatch.setattr(tree_file, "append_depth", real_append)
    calls = _count_depths(monkeypatch)
    backward_sample(expert, str(out), config, progress=False)
    return calls


def _finished_tree_to_grow(expert: str, out, config: SamplerConfig) -> int:
    """Sample a complete tree at ``out`` and leave it as ``out``'s partial file, as a run growing it finds it; its node
    count."""
    backward_sample(expert, str(out), config, progress=False)
    with h5py.File(out, "r") as f:
        n = len(f["depth"])
    out.rename(out.with_name(out.name + ".partial"))
    return n


@pytest.mark.slow
def test_sampler_fails_clearly_then_resumes(pipeline, tmp_path, monkeypatch):
    out = tmp_path / "tree.h5"
    with pytest.raises(NoStartRegionError, match="max_depth=3"):
        backward_sample(pipeline["expert"], str(out), _unrendered(max_depth=3), progress=False)
    partial = out.with_name(out.name + ".partial")
    with h5py.File(partial, "r") as f:
        assert f.attrs["completed_depth"] == 3
    # The interrupted run resumes from depth 3 (it samples none of depths 0-3 again) and, with
    # max_depth raised, completes. Depths 0-3 are the uninterrupted run's, node for node; later ones
    # may differ a little, since PhysX's contact cache (PCM) is not part of a saved state.
    calls = _count_depths(monkeypatch)
    backward_sample(pipeline["expert"], str(out), _unrendered(max_depth=3 + 37), progress=False)
    assert calls and min(calls) == 4
    assert not partial.exists()
    with h5py.File(out, "r") as a, h5py.File(pipeline["tree"], "r") as b:
        kept = a["depth"][()] <= 3
        assert kept.sum() == (b["depth"][()] <= 3).sum() == 1 + 3 * 4
        np.testing.assert_allclose(a["tcp_pose"][()][kept], b["tcp_pose"][()][: kept.sum()], atol=1e-6)
        last_seed = np.nonzero(a["is_seed"][()])[0][-1]
        assert a["in_start_region"][last_seed] and a.attrs["complete"]
        assert json.loads(a.attrs["header"])["config"]["max_depth"] == 40  # the resuming run's
        np.testing.assert_array_equal(a["colors"][()], b["colors"][()])



@pytest.mark.slow
def test_outward_lineages_leave_the_start_region_along_their_directions_and_resume(pipeline, tmp_path, monkeypatch):
    config = _unrendered(phases=dict(outward=dict(depth=3, lineages=4, children=6)))
    out = tmp_path / "tree.h5"
    calls = _interrupt_then_resume(  # interrupted in the outward phase's second depth, then resumed
        pipeline["expert"], out, config, monkeypatch,
        lambda path, depth, chosen, kw: len(chosen) == 4
        and depth == int(h5py.File(path, "r").attrs["start_depth"]) + 2)
    assert calls == [calls[0] + i for i in range(len(calls))] and len(calls) == 2  # outward depths 2 and 3 only
    with h5py.File(out, "r") as f, h5py.File(pipeline["tree"], "r") as ref:
        start, final = int(f.attrs["start_depth"]), int(f.attrs["final_depth"])
        depth, parent, tcp, seed = f["depth"][()], f["parent"][()], f["tcp_pose"][()], f["is_seed"][()]
        # The backward phase is the tree without the outward phase, node for node.
        n = len(ref["depth"])
        assert start == ref["depth"][()].max() and final == start + 3
        np.testing.assert_allclose(tcp[:n], ref["tcp_pose"][()], atol=1e-4)
        assert np.all(np.bincount(depth)[start + 1:] == 4 * 6)
        origin = tcp[np.nonzero(seed & (depth == start))[0][0], :3]
        assert np.all(parent[depth == start + 1] == np.nonzero(seed & (depth == start))[0][0])
        along = []
        for d in range(start + 1, final + 1):
            seeds = np.nonzero(seed & (depth == d))[0]  # lineage order
            assert len(seeds) == 4
            if d > start + 1:  # each lineage's children hang under its own previous seed
                kids = np.nonzero(depth == d)[0].reshape(4, 6)
                assert np.all(parent[kids] == np.nonzero(seed & (depth == d - 1))[0][:, None])
            along.append(np.einsum("lx,lx->l", tcp[seeds, :3] - origin, outward_directions(config.phases["outward"])))
        along = np.array(along)
        # Each lineage moves away along its own direction, a centimetre or more in three steps.
        assert np.all(np.diff(along, axis=0) > 0) and np.all(along[-1] > 0.01), along

@pytest.mark.slow
def test_each_child_gets_its_own_colours_which_do_not_change_its_step(pipeline):
    """The image branch must see the colour randomisation every reset applies; colours are not physics."""
    with h5py.File(pipeline["tree"], "r") as f:
        colors, depth = f["colors"][()], f["depth"][()]
    assert colors.shape == (len(depth), 6)
    children = colors[depth == 1]
    assert len(np.unique(children.round(6), axis=0)) == len(children) > 1
    lo, hi = PegInHoleEnv.color_range
    assert colors.min() >= lo and colors.max() <= hi
    sampler = ChildSampler("PegInHole-v1", {}, episode_seed=5)
    try:
        # The root is the expert's episode, in that episode's colours.
        np.testing.assert_allclose(colors[0], sampler.adapter.colors()[0].numpy(), atol=1e-6)
        seed_state = sampler.adapter.get_state()
        actions = sampler.random_actions(np.random.default_rng(0), 2, 1.0)
        a = sampler.children(seed_state, actions, sampler.random_colors(np.random.default_rng(1), 2))
        b = sampler.children(seed_state, actions, sampler.random_colors(np.random.default_rng(2), 2))
        for key in ("state", "tcp_pose", "ft"):
            np.testing.assert_array_equal(a[key], b[key])  # the same step, whatever the colours
        assert not np.allclose(a["colors"], b["colors"])
        assert np.abs(a["fixed_rgb"].astype(int) - b["fixed_rgb"].astype(int)).mean() > 1.0
    finally:
        sampler.close()


@pytest.mark.slow
def test_each_child_is_moved_to_its_own_socket_placement_which_does_not_change_its_step(pipeline):
    """Every reset places the socket anew; the tree shows the encoder those placements, the step unchanged."""
    with h5py.File(pipeline["tree"], "r") as f:
        placement, depth = f["placement"][()], f["depth"][()]
    assert placement.shape == (len(depth), 3)
    children = placement[depth == 1]
    assert len(np.unique(children.round(6), axis=0)) == len(children) > 1
    center, r, yaw = np.asarray(PegInHoleEnv.socket_center), PegInHoleEnv.socket_xy_range, PegInHoleEnv.socket_yaw_range
    assert np.all(np.abs(placement[1:, :2] - center) <= r + 1e-6) and np.all(np.abs(placement[1:, 2]) <= yaw + 1e-6)
    sampler = ChildSampler("PegInHole-v1", {}, episode_seed=5)
    try:
        u = sampler.unwrapped
        # Pressed on the face beside the opening: contact is where a moved scene would show first.
        hold = HoldPolicy(u, HOLD_POSITIONS["pressed 3 mm beside"])
        for _ in range(12):
            sampler.env.step(hold.act())
        seed_state = sampler.adapter.get_state()
        actions = np.array([[0.0, 0.05, -0.8, 0.0, 0.0, 0.1]] * 2)  # press harder, slide and twist
        a = sampler.children(seed_state, actions, placements=np.array([[0.535, 0.012, 0.2], [0.565, -0.018, -0.25]]))
        b = sampler.children(seed_state, actions)  # where the seed had it
        np.testing.assert_allclose(a["placement"], [[0.535, 0.012, 0.2], [0.565, -0.018, -0.25]], atol=1e-5)
        # The same step in the socket's frame, and the same pose once moved back to the expert's placement.
        # (A step that slides off the block's edge can differ by a substep: there PhysX is chaotic.)
        np.testing.assert_allclose(a["tip_in_socket"], b["tip_in_socket"], atol=2e-5)
        np.testing.assert_allclose(a["tcp_pose"], b["tcp_pose"], atol=1e-4)
        np.testing.assert_allclose(a["ft"], b["ft"], atol=0.5, rtol=0.02)
        assert np.abs(b["ft"][:, -1, 2]).max() > 10.0  # pressing on the face
        assert np.abs(a["fixed_rgb"][0].astype(int) - a["fixed_rgb"][1].astype(int)).mean() > 1.0
        assert u.socket_placements().shape == (u.num_envs, 3)
    finally:
        sampler.close()


@pytest.mark.parametrize("task", TASKS)
def test_shipped_expert_demos_reach_the_goal(task):
    from pathlib import Path

    from drem_maniskill.pipeline.tree.expert import load_expert
    from drem_maniskill.utils.state import broadcast_state, state_at

    expert = load_expert(str(Path(__file__).parents[2] / "tasks" / task / "expert.h5"))
    assert expert.env_id == task and expert.episode_seed == 1000 and expert.length > 5
    env = gym.make(task, obs_mode="state_dict")
    try:
        env.reset(seed=expert.episode_seed)
        env.unwrapped.set_state_dict(broadcast_state(state_at(expert.states, 0), 1))
        assert env.unwrapped.in_start_region().item()
        env.unwrapped.set_state_dict(broadcast_state(state_at(expert.states, expert.length - 1), 1))
        assert env.unwrapped.evaluate()["success"].item()
    finally:
        env.close()


def test_actions_follow_the_experts_step_when_asked():
    """expert_step_scale: the action range at depth d is k times the expert's step there, within the bounds."""
    from drem_maniskill.pipeline.tree.backward import action_scale_at

    # An expert that moves 1 cm per step, then 2 mm per step over its last three steps.
    x = np.array([0.0, 0.01, 0.02, 0.03, 0.032, 0.034, 0.036])
    ee = np.zeros((len(x), 8))
    ee[:, 2] = x
    config = SamplerConfig(expert_step_scale=2.0, min_action_scale=0.05, action_scale=1.0)
    # Depth 0 -> 1: the expert's last step (2 mm) at 2 cm per full action: 2 x 0.1 = 0.2.
    assert action_scale_at(0, ee, config, 0.02) == pytest.approx(0.2)
    assert action_scale_at(3, ee, config, 0.02) == pytest.approx(1.0)  # 2 x 1 cm = 2 cm: the whole range
    # Past the demo's start, a chain still short of it goes on at the demo's median step: (1 cm + 2 mm) / 2 = 6 mm.
    assert action_scale_at(6, ee, config, 0.02) == action_scale_at(40, ee, config, 0.02) == pytest.approx(0.6)
    assert action_scale_at(40, np.zeros((4, 8)), config, 0.02) == pytest.approx(0.05)  # a demo that never moves: floor
    assert action_scale_at(0, ee, SamplerConfig(action_scale=0.7), 0.02) == 0.7  # off: the fixed range


def test_slide_step_draws_the_lineages_children_within_that_fraction_of_the_loops_range(monkeypatch):
    """phases.slide.step: each lineage's children come from that fraction of the backward loop's range at its origin;
    a step outside (0, 1] is refused."""
    from types import SimpleNamespace

    from drem_maniskill.pipeline.tree.phases import base, slide

    asked = []

    class Pool:
        def children_of(self, seeds, nodes, depth, count, scale, stream, shape):
            asked.append(scale)
            raise StopIteration  # the range is all this test reads

    monkeypatch.setattr(slide, "origin_poses", lambda ctx, reach, every: np.zeros((1, 7)))
    monkeypatch.setattr(slide, "approach_of", lambda path, reach, start: np.array([0.0, 0.0, -1.0]))
    monkeypatch.setattr(base, "near_goal_depths", lambda reach, every, start: [1])
    monkeypatch.setattr(base.tree_file, "read_seeds", lambda group: ([object()], [7]))

    class File:
        attrs = {}

        def __init__(self, *args):
            pass

        def __enter__(self):
            return self

        def __exit__(self, *args):
            return False

        def __getitem__(self, key):
            return None

    monkeypatch.setattr(base.h5py, "File", File)
    ctx = base.PhaseContext(partial=Path("tree.h5"), pool=Pool(), config=None, start_depth=10,
                            backward_scale=lambda depth: 0.4, geometry=None, progress=False)
    monkeypatch.setattr(base.PhaseContext, "sampler", property(lambda self: SimpleNamespace(translation_limit=0.02)))
    for step in (1.0, 0.25):
        with pytest.raises(StopIteration):
            slide.sample_slide(ctx, slide.SlideConfig(depth=3, lineages=2, step=step))
    assert asked == [pytest.approx(0.4), pytest.approx(0.1)]
    for step in (0.0, 1.5):
        with pytest.raises(ValueError, match="phases.slide.step"):
            slide.SlideConfig(depth=3, step=step)


def test_slide_lineages_start_up_to_reach_and_move_across_the_approach_of_approach_reach(monkeypatch):
    """phases.slide.approach_reach: the origins come from ``reach`` of the loop's depths, the approach from
    ``approach_reach`` of them (``reach`` when left out); a value outside (0, 1] is refused."""
    from types import SimpleNamespace

    from drem_maniskill.pipeline.tree.phases import slide

    asked = {}
    monkeypatch.setattr(slide, "origin_poses", lambda ctx, reach, every: asked.setdefault("origins", reach)
                        and np.zeros((2, 7)))
    monkeypatch.setattr(slide, "approach_of", lambda path, reach, start: asked.setdefault("approach", reach)
                        and np.array([0.0, 0.0, -1.0]))
    monkeypatch.setattr(slide, "grow_near_goal_lineages", lambda *args, **kwargs: None)
    ctx = SimpleNamespace(partial=Path("tree.h5"), start_depth=10, sampler=SimpleNamespace(translation_limit=0.02))
    for settings, expected in ((dict(reach=1.0, approach_reach=0.5), (1.0, 0.5)), (dict(reach=0.75), (0.75, 0.75))):
        asked.clear()
        slide.sample_slide(ctx, slide.SlideConfig(depth=3, lineages=2, **settings))
        assert (asked["origins"], asked["approach"]) == expected
    for value in (0.0, 1.5):
        with pytest.raises(ValueError, match="phases.slide.approach_reach"):
            slide.SlideConfig(depth=3, approach_reach=value)


def test_twist_step_turns_the_lineages_children_within_that_fraction_of_the_rotation_step(monkeypatch):
    """phases.twist.step: the children's rotation spans that fraction of the controller's full rotation range, and a
    lineage ends below ``min_turn`` of that range; a step outside (0, 1] is refused."""
    from types import SimpleNamespace

    from drem_maniskill.pipeline.tree.phases import twist

    grown = []
    monkeypatch.setattr(twist, "origin_poses", lambda ctx, reach, every: np.array([[0.0, 0, 0, 1, 0, 0, 0]]))
    monkeypatch.setattr(twist, "grow_near_goal_lineages", lambda *args, **kwargs: grown.append((args[6], kwargs)))
    ctx = SimpleNamespace(partial=Path("tree.h5"), start_depth=10, config=SimpleNamespace(action_scale=1.0),
                          sampler=SimpleNamespace(rotation_dims=[3, 4, 5], rotation_limit=0.05))
    for step in (1.0, 0.25):
        twist.sample_twist(ctx, twist.TwistConfig(depth=3, step=step, min_turn=0.5))
    for (least, kwargs), step in zip(grown, (1.0, 0.25)):
        actions = kwargs["shape"](np.full((2, 6), 0.1), 0.1)  # drawn within the loop's range 0.1
        np.testing.assert_allclose(actions[:, :3], 0.1)  # the translation stays within the loop's range
        np.testing.assert_allclose(actions[:, 3:], step)  # the rotation spans step of the full range
        assert least(0.1) == pytest.approx(0.5 * 0.05 * step)
    for step in (0.0, 1.5):
        with pytest.raises(ValueError, match="phases.twist.step"):
            twist.TwistConfig(depth=3, step=step)


def test_wander_directions_are_fixed_by_the_seed_and_read_across_the_approach_and_in_the_end_effectors_frame():
    """Wander lineages: unit five-vectors drawn once from the sampler's seed; their first two components move the part
    across the approach, the last three turn it about the end effector's axes at the origin (world frame)."""
    import torch
    from mani_skill.utils.geometry.rotation_conversions import quaternion_to_matrix

    from drem_maniskill.pipeline.tree.phases.wander import wander_axes, wander_directions

    directions = wander_directions(16, 0)
    np.testing.assert_allclose(np.linalg.norm(directions, axis=1), 1)
    np.testing.assert_array_equal(directions, wander_directions(16, 0))  # a resume draws the same lineages
    assert not np.allclose(directions, wander_directions(16, 1))
    approach = np.array([0.0, 0.6, -0.8])
    q = np.array([[1.0, 0, 0, 0], [np.cos(0.4), np.sin(0.4), 0, 0]])  # upright, and turned 0.8 rad about x
    slide, turn = wander_axes(q, approach, directions)
    assert slide.shape == turn.shape == (32, 3)
    np.testing.assert_allclose(slide @ approach, 0, atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(slide, axis=1), np.tile(np.linalg.norm(directions[:, :2], axis=1), 2))
    np.testing.assert_allclose(slide[:16], slide[16:])  # the same plane from every origin
    np.testing.assert_allclose(turn[:16], directions[:, 2:])  # the world's axes at an upright origin
    frame = quaternion_to_matrix(torch.as_tensor(q[1])).numpy()
    np.testing.assert_allclose(turn[16:], directions[:, 2:] @ frame.T, atol=1e-12)


def test_wander_scores_children_in_step_units_and_draws_them_within_its_ranges(monkeypatch):
    """phases.wander.step and turn_step: the children's translation spans ``step`` of the loop's range at the origin,
    their rotation ``turn_step`` of the controller's step, and a child one step's reach along its lineage's direction
    (either way: a slide or a turn) scores 1; a lineage ends below ``min_move`` of a step; a step outside (0, 1] is
    refused."""
    from types import SimpleNamespace

    from drem_maniskill.pipeline.tree.phases import wander

    grown = []
    monkeypatch.setattr(wander, "origin_poses", lambda ctx, reach, every: np.array([[0.0, 0, 0, 1, 0, 0, 0]] * 2))
    monkeypatch.setattr(wander, "near_goal_depths", lambda reach, every, start: [1, 5])
    monkeypatch.setattr(wander, "approach_of", lambda path, reach, start: np.array([0.0, 0.0, -1.0]))
    monkeypatch.setattr(wander, "grow_near_goal_lineages", lambda *args, **kwargs: grown.append((args, kwargs)))
    ctx = SimpleNamespace(partial=Path("tree.h5"), start_depth=10, config=SimpleNamespace(action_scale=1.0, seed=3),
                          backward_scale=lambda depth: 0.5 if depth == 1 else 1.0,
                          sampler=SimpleNamespace(rotation_dims=[3, 4, 5], rotation_limit=0.05, translation_limit=0.02))
    wander.sample_wander(ctx, wander.WanderConfig(depth=3, lineages=4, step=0.5, turn_step=0.25, min_move=0.3))
    (args, kwargs), = grown
    gained, least = args[5], args[6]
    assert args[4] == 4 and kwargs["range_scale"] == 0.5 and least(0.123) == 0.3
    actions = kwargs["shape"](np.full((2, 6), 0.25), 0.25)  # drawn within the loop's range 0.25
    np.testing.assert_allclose(actions[:, :3], 0.25)
    np.testing.assert_allclose(actions[:, 3:], 0.25)  # the rotation spans turn_step of the full range
    slide, turn = wander.wander_axes(np.array([[1.0, 0, 0, 0]] * 2), np.array([0.0, 0.0, -1.0]),
                                     wander.wander_directions(4, 3))
    unit_slide = slide / np.linalg.norm(slide, axis=1, keepdims=True)
    unit_turn = turn / np.linalg.norm(turn, axis=1, keepdims=True)
    # Lineage 1 (origin depth 1, translation reach 0.5 * 0.5 * 2 cm) and lineage 6 (depth 5, reach 0.5 * 2 cm).
    for lineage, metres in ((1, 0.005), (6, 0.01)):
        moved = np.concatenate([unit_slide[lineage] * metres / np.linalg.norm(slide[lineage]), [1.0, 0, 0, 0]])
        np.testing.assert_allclose(gained(moved[None], np.array([lineage])), 1.0)
        angle = 0.05 * 0.25 / np.linalg.norm(turn[lineage])  # a turn about its axis worth one step of its direction
        q = np.concatenate([[np.cos(angle / 2)], np.sin(angle / 2) * unit_turn[lineage]])
        np.testing.assert_allclose(gained(np.concatenate([[0.0, 0, 0], q])[None], np.array([lineage])), 1.0)
    for key in ("step", "turn_step"):
        for value in (0.0, 1.5):
            with pytest.raises(ValueError, match=f"phases.wander.{key}"):
                wander.WanderConfig(depth=3, **{key: value})


def test_even_path_splits_the_demos_long_steps_into_its_median_step_and_keeps_its_poses():
    """even_path: a demo of 2 mm steps ending in two 6 mm pushes walks the pushes in 2 mm steps too, through the
    recorded poses, the goal last; the quaternion takes the short way round and stays a unit one."""
    from drem_maniskill.pipeline.tree.backward import ee_distance, even_path

    z = np.array([0.0, 0.002, 0.004, 0.006, 0.008, 0.014, 0.020])
    ee = np.zeros((len(z), 8))
    ee[:, 2], ee[:, 3], ee[:, 7] = z, 1.0, np.linspace(0.04, 0.0, len(z))
    ee[-1, 3] = -1.0  # the same orientation, the other sign
    path = even_path(ee, rotation_weight=0.05)
    assert len(path) == 4 + 3 + 3 + 1
    np.testing.assert_allclose(ee_distance(path[:-1], path[1:], 0.05), 0.002, atol=1e-9)
    np.testing.assert_array_equal(path[[0, 4, 7, 10]], ee[[0, 4, 5, 6]])  # the recorded poses themselves
    np.testing.assert_allclose(np.linalg.norm(path[:, 3:7], axis=1), 1.0)
    np.testing.assert_allclose(path[8, 7], (2 * ee[5, 7] + ee[6, 7]) / 3)  # the gripper width in between
    assert even_path(ee[:5], 0.05).shape == ee[:5].shape  # even already: unchanged
    with pytest.raises(ValueError, match="seeds_from_demo"):
        SamplerConfig(even_path=True, seeds_from_demo=True)


def test_a_graded_path_crowds_its_depths_toward_the_goal_on_the_demos_own_path():
    """graded_path: a straight 60 mm demo of 3 mm steps is walked from the goal in steps of a tenth of the way left,
    0.75 mm (a quarter of the median step) at the goal up to the median step far from it, every pose on the demo's
    path, the first and the goal kept."""
    from drem_maniskill.pipeline.tree.backward import ee_distance, graded_path

    z = np.arange(0.0, 0.0601, 0.003)[::-1]
    ee = np.zeros((len(z), 8))
    ee[:, 2], ee[:, 3] = z, 1.0
    path = graded_path(ee, rotation_weight=0.05, fraction=0.1, finest=0.25)
    steps = ee_distance(path[:-1], path[1:], 0.05)[::-1] * 1000  # mm, from the goal out
    left = path[::-1, 2][1:] * 1000  # how far from the goal each step ends
    np.testing.assert_array_equal(path[[0, -1]], ee[[0, -1]])
    np.testing.assert_allclose(path[:, [0, 1, 3, 4, 5, 6, 7]], np.tile(ee[0, [0, 1, 3, 4, 5, 6, 7]], (len(path), 1)))
    assert steps[0] == pytest.approx(0.75) and steps.max() == pytest.approx(3.0)
    # a step is the first 0.75 mm multiple of at least a tenth of the way already walked, at most the median step
    walked = left - steps
    np.testing.assert_allclose(steps[:-1], np.clip(np.ceil(np.maximum(0.1 * walked[:-1], 0.75) / 0.75 - 1e-9) * 0.75,
                                                   None, 3.0), atol=1e-9)
    assert len(path) == 33 and (np.diff(path[:, 2]) < 0).all()  # 21 poses at 3 mm; more, and always nearer the goal
    with pytest.raises(ValueError, match="turn even_path on"):
        SamplerConfig(graded_path=0.1)
    with pytest.raises(ValueError, match="graded_finest"):
        SamplerConfig(even_path=True, graded_path=0.1, graded_finest=0.0)


def test_lineages_never_keep_a_child_caught_in_the_opening_and_do_not_keep_the_children_that_went_in():
    """A face lineage takes a child on the face over a farther one caught in the opening's mouth, or, all caught,
    the least deep; a side lineage takes one beside the block over one in the opening; children in the opening are
    not kept (they are labelled by their lineage, and may be a step from the goal)."""
    from drem_maniskill.pipeline.tree.phases.base import caught_penalty, farthest_along, out_of_opening

    directions = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
    ee, tip = np.zeros((6, 3)), np.zeros((6, 3))  # 2 lineages x 3 children; metres, tips in the socket frame
    ee[:3, 0], tip[:3] = [0.003, 0.001, 0.004], [[0.0005, 0, -0.0004], [0.0015, 0, 0.0001], [0.0003, 0, -0.005]]
    ee[3:, 1], tip[3:, 2] = [0.003, 0.002, 0.001], [-0.0006, -0.0003, -0.002]  # all three in the mouth
    chosen = farthest_along(ee, np.zeros(3), directions, caught_penalty(tip, GEOMETRY, side=False))
    assert list(chosen) == [1, 4]  # on the face, not 2 mm farther in the mouth; the least deep of the caught
    assert list(farthest_along(ee, np.zeros(3), directions)) == [2, 3]  # what the distance alone would take
    kept, new, dropped = out_of_opening(dict(tip_in_socket=tip, ee=ee, parent=np.arange(6)), chosen, GEOMETRY)
    assert list(in_opening(tip)) == [False, False, True, False, False, True] and dropped == 2
    assert list(kept["parent"]) == [0, 1, 3, 4] and list(kept["parent"][new]) == [1, 4]
    assert not in_opening(kept["tip_in_socket"]).any()
    # Side phase: down the block's side (2 cm off the axis, 10 mm down) is where it should go; 5 mm down the opening
    # is not.
    side_tip = np.array([[0.002, 0, -0.005], [0.02, 0, -0.01], [0.0, 0, 0.001], [0, 0.012, -0.002],
                         [0, 0.003, -0.004], [0, 0, 0]])
    side_ee = np.array([[0.005, 0, 0], [0.004, 0, 0], [0.0, 0, 0], [0, 0.002, 0], [0, 0.006, 0], [0, 0, 0]])
    penalty = caught_penalty(side_tip, GEOMETRY, side=True)
    assert list(farthest_along(side_ee, np.zeros(3), directions, penalty)) == [1, 3]
    _, _, dropped = out_of_opening(dict(tip_in_socket=side_tip), np.zeros(0, np.int64), GEOMETRY)
    assert dropped == 2


@pytest.mark.slow
def test_face_lineages_slide_the_part_from_the_opening_over_the_face_and_resume(pipeline, tmp_path, monkeypatch):
    """Each face lineage moves out of the opening along its direction, one depth per step, and resumes."""
    config = _unrendered(phases=dict(face=dict(depth=3, lineages=4, children=6)))
    out = tmp_path / "tree.h5"
    calls = _interrupt_then_resume(  # interrupted in the face phase's second depth, then resumed
        pipeline["expert"], out, config, monkeypatch, lambda path, depth, chosen, kw: kw.get("group") == "face_2")
    assert calls == ["face_2", "face_3"]
    with h5py.File(out, "r") as f, h5py.File(pipeline["tree"], "r") as ref:
        n = len(ref["depth"])
        np.testing.assert_allclose(f["tcp_pose"][:n], ref["tcp_pose"][()], atol=1e-4)
        entry = face_entry_depth(out, int(f.attrs["start_depth"]))
        dropped = [int(f[f"seeds/face_{k}"].attrs["dropped_in_opening"]) for k in range(1, 4)]
        assert int(f.attrs["face_completed"]) == 3 and len(f["depth"]) == n + 3 * 4 * 6 - sum(dropped)
        depth, parent, tip, tcp = f["depth"][n:], f["parent"][n:], f["tip_in_socket"][()], f["tcp_pose"][()]
        assert not in_opening(tip[n:]).any()  # the children that went in are not kept
        # Face step k's nodes are k small moves from the seed at the opening, which is `entry` from the goal.
        assert np.array_equal(depth, np.repeat(entry + np.arange(1, 4), [24 - d for d in dropped]))
        entry_node = int(f["seeds/depth_%d/node" % entry][0])
        assert np.all(parent[: 24 - dropped[0]] == entry_node)
        assert tip[entry_node, 2] > FACE_ENTRY_HEIGHT >= tip[int(f["seeds/depth_%d/node" % (entry - 1)][0]), 2]
        along = []
        for k in range(1, 4):
            seeds = f[f"seeds/face_{k}/node"][()]
            assert len(seeds) == 4 and np.all(tip[seeds, 2] > FACE_SEED_HEIGHT)  # out of the opening
            if k > 1:  # each lineage's children hang under its own previous seed
                kids = n + sum(24 - d for d in dropped[: k - 1]) + np.arange(24 - dropped[k - 1])
                per_seed = [(f["parent"][()][kids] == s).sum() for s in f[f"seeds/face_{k - 1}/node"][()]]
                assert max(per_seed) <= 6 and sum(per_seed) == 24 - dropped[k - 1]
            flat = face_directions(config.phases["face"])[:, :2]
            flat = flat / np.linalg.norm(flat, axis=1, keepdims=True)
            along.append(np.einsum("lx,lx->l", tcp[seeds, :2] - tcp[entry_node, :2], flat))
        along = np.array(along)
        # Each lineage slides away from the opening along its own direction, a millimetre or more in three steps (of 6
        # children each).
        assert np.all(np.diff(along, axis=0) > 0) and np.all(along[-1] > 0.001), along


@pytest.mark.slow
def test_side_lineages_go_on_from_the_face_lineages_and_a_finished_tree_gains_them(pipeline, tmp_path, monkeypatch):
    """The side phase continues each face lineage, labelled past it, along its steep direction; a complete tree without
    it gains it by a resume that samples the side depths alone, and an interrupted side phase resumes."""
    face = _unrendered(phases=dict(face=dict(depth=2, lineages=4, children=6)))
    out = tmp_path / "tree.h5"
    backward_sample(pipeline["expert"], str(out), face, progress=False)
    with pytest.raises(ValueError, match="face.depth"):
        backward_sample(pipeline["expert"], str(tmp_path / "x.h5"),
                        _unrendered(phases=dict(side=dict(depth=2))), progress=False)
    grown = tmp_path / "grown.h5"
    grown.with_name(grown.name + ".partial").write_bytes(out.read_bytes())
    side = _unrendered(phases=dict(face=dict(depth=2, lineages=4, children=6),
                                                    side=dict(depth=3, children=6)))
    calls = _interrupt_then_resume(pipeline["expert"], grown, side, monkeypatch,
                                   lambda path, depth, chosen, kw: kw.get("group") == "side_2")
    assert calls == ["side_2", "side_3"]  # nothing of the tree it grew from again
    with h5py.File(grown, "r") as f, h5py.File(out, "r") as ref:
        n = len(ref["depth"])
        np.testing.assert_array_equal(f["depth"][:n], ref["depth"][()])
        entry = face_entry_depth(grown, int(f.attrs["start_depth"]))
        dropped = [int(f[f"seeds/side_{k}"].attrs["dropped_in_opening"]) for k in range(1, 4)]
        assert int(f.attrs["side_completed"]) == 3 and len(f["depth"]) == n + 3 * 4 * 6 - sum(dropped)
        assert not in_opening(f["tip_in_socket"][n:]).any()
        # Side step k's nodes are labelled past the face phase's last: entry + face depth + k.
        assert np.array_equal(f["depth"][n:], np.repeat(entry + 2 + np.arange(1, 4), [24 - d for d in dropped]))
        parent, tcp = f["parent"][()], f["tcp_pose"][()]
        per_seed = [(parent[n : n + 24 - dropped[0]] == s).sum() for s in f["seeds/face_2/node"][()]]
        # Six from each face lineage's end, less those dropped.
        assert max(per_seed) <= 6 and sum(per_seed) == 24 - dropped[0]
        directions = face_directions(side.phases["face"], side.phases["side"].elevation)
        assert np.all(directions[:, 2] < -0.8)  # steeply down
        origin = tcp[int(f["seeds/depth_%d/node" % entry][0]), :3]
        along = np.array([np.einsum("lx,lx->l", tcp[f[f"seeds/side_{k}/node"][()], :3] - origin, directions)
                          for k in range(1, 4)])
        assert np.all(np.diff(along, axis=0) > 0), along  # each lineage goes on along its own direction
    assert json.loads(h5py.File(grown, "r").attrs["header"])["config"]["phases"]["side"]["depth"] == 3


@pytest.mark.slow
def test_push_children_leave_every_face_and_side_seed_with_full_range_actions_one_depth_past_it(pipeline, tmp_path,
                                                                                               monkeypatch):
    """Push children: from each face and side seed, full-range actions, labelled one past the seed, never seeds;
    resumable."""
    from drem_maniskill.pipeline.tree.phases.push import push_groups

    base = dict(face=dict(depth=2, lineages=4, children=6), side=dict(depth=1, children=6))
    grown = tmp_path / "tree.h5"
    n = _finished_tree_to_grow(pipeline["expert"], grown, _unrendered(phases=base))
    config = _unrendered(phases=dict(base, push=dict(children=5)))
    assert push_groups(config) == ["face_1", "face_2", "side_1"]
    calls = _interrupt_then_resume(pipeline["expert"], grown, config, monkeypatch,
                                   lambda path, depth, chosen, kw: kw.get("group") == "push_2")
    assert calls == ["push_2", "push_3"]
    with h5py.File(grown, "r") as f:
        dropped = sum(int(f[f"seeds/push_{i}"].attrs["dropped_in_opening"]) for i in range(1, 4))
        assert int(f.attrs["push_completed"]) == 3 and len(f["depth"]) == n + 3 * 4 * 5 - dropped
        depth, parent, tcp = f["depth"][()], f["parent"][()], f["tcp_pose"][()]
        kids = np.arange(n, len(depth))
        assert not in_opening(f["tip_in_socket"][n:]).any()
        seeds = np.concatenate([f[f"seeds/{g}/node"][()] for g in push_groups(config)])
        # From the seeds, in group order.
        assert np.all(np.isin(parent[kids], seeds)) and np.all(np.diff(parent[kids]) >= 0)
        per_seed = [(parent[kids] == s).sum() for s in seeds]
        # Five from each seed, less those dropped.
        assert max(per_seed) <= 5 and sum(per_seed) == len(seeds) * 5 - dropped
        assert np.array_equal(depth[kids], depth[parent[kids]] + 1) and not f["is_seed"][()][kids].any()
        moved = np.linalg.norm(tcp[kids, :3] - tcp[parent[kids], :3], axis=1)
        lineage = np.arange(n - 4 * 6, n)  # the side phase's children: 4 mm actions
        lineage_moved = np.linalg.norm(tcp[lineage, :3] - tcp[parent[lineage], :3], axis=1)
        assert moved.max() > 2 * lineage_moved.max()  # full-range actions reach much farther than the lineage steps


@pytest.mark.slow
def test_turn_lineages_turn_the_part_about_their_own_axes_near_the_opening_labelled_a_step_per_turn(pipeline, tmp_path,
                                                                                                    monkeypatch):
    """Turn lineages start at the hover and face seeds near the opening, each turning farther about its own axis at
    every step (more than the upright phases ever turn the part), labelled their first seed's label plus the step; none
    in the opening; a finished tree gains them, and an interrupted phase resumes."""
    from drem_maniskill.pipeline.tree.phases.base import rotation_vectors
    from drem_maniskill.pipeline.tree.phases.turn import turn_axes, turn_origins

    base = dict(face=dict(depth=2, lineages=2, children=6))
    grown = tmp_path / "tree.h5"
    n = _finished_tree_to_grow(pipeline["expert"], grown, _unrendered(phases=base))
    with pytest.raises(ValueError, match="face.depth"):
        backward_sample(pipeline["expert"], str(tmp_path / "x.h5"),
                        _unrendered(phases=dict(turn=dict(depth=2))), progress=False)
    config = _unrendered(phases=dict(base, turn=dict(depth=3, children=6)))
    calls = _interrupt_then_resume(pipeline["expert"], grown, config, monkeypatch,
                                   lambda path, depth, chosen, kw: kw.get("group") == "turn_2")
    assert calls == ["turn_2", "turn_3"]  # nothing of the tree it grew from again
    with h5py.File(grown, "r") as f:
        origins = turn_origins(grown, config, int(f.attrs["start_depth"]))
        entry = face_entry_depth(grown, int(f.attrs["start_depth"]))
        hover = [f"depth_{entry + d}" for d in (0, 2, 4)]
        # The backward seeds above the entry that are out of the opening (a tiny tree's may have gone back in), then
        # every face lineage's second seed.
        out = [g for g in hover if not in_opening(f["tip_in_socket"][[int(f[f"seeds/{g}/node"][0])]])[0]]
        assert [g for g, _, _ in origins] == out + ["face_2", "face_2"] and out[0] == hover[0]
        lineages = len(origins) * config.phases["turn"].lineages
        dropped = [int(f[f"seeds/turn_{k}"].attrs["dropped_in_opening"]) for k in range(1, 4)]
        assert int(f.attrs["turn_completed"]) == 3 and len(f["depth"]) == n + 3 * lineages * 6 - sum(dropped)
        assert not in_opening(f["tip_in_socket"][n:]).any()
        depth, tcp = f["depth"][()], f["tcp_pose"][()].astype(np.float64)
        first = np.repeat([int(f[f"seeds/{g}/node"][i]) for g, i, _ in origins], config.phases["turn"].lineages)
        labels = np.repeat([label for _, _, label in origins], config.phases["turn"].lineages)
        # face_2's seeds are labelled entry + 2.
        assert sorted(set(labels)) == sorted({entry, entry + 2} | {int(g[6:]) for g in out})
        axes, along = turn_axes(config.phases["turn"], len(origins)), []
        for k in range(1, 4):
            seeds = f[f"seeds/turn_{k}/node"][()]
            assert np.array_equal(depth[seeds], labels + k)
            assert np.array_equal(f[f"seeds/turn_{k}"].attrs["label"], labels + k)
            along.append(np.einsum("lx,lx->l", rotation_vectors(tcp[seeds, 3:7], tcp[first, 3:7]), axes))
        along = np.array(along)
        # Each lineage turns farther along its own axis at every step (the controller turns up to 0.05 rad a step; the
        # best of 6 random children about half that), more than a whole step in three.
        assert np.all(np.diff(along, axis=0) > 0) and np.all(along[-1] > 0.05), along
        # More than the upright phases ever turn the part: the face seeds they start from.
        face = f["seeds/face_2/node"][()]
        entry_node = int(f[f"seeds/depth_{entry}/node"][0])
        face_turns = rotation_vectors(tcp[face, 3:7], tcp[[entry_node] * len(face), 3:7])
        assert np.linalg.norm(face_turns, axis=1).max() < along[-1].min()


def _grow_near_goal_lineages(pipeline, tmp_path, monkeypatch, name: str, settings: dict, per_origin: int,
                             progress, least: float) -> tuple:
    """Grow the pipeline's finished tiny tree with the near-goal phase ``name`` (3 steps from every fourth of the first
    half of its depths), interrupted in its second step and resumed, never reading the socket geometry; check what
    every such phase does and return the tree's path, its origins' nodes and the live lineages' final progress.

    Every step gives each live lineage ``settings["children"]`` children labelled its origin's depth plus the step; a
    lineage keeps the child ``progress(tcp [n, 7], origin tcp [n, 7], lineage [n])`` puts farthest, gaining at least
    ``least`` on the step before, and a lineage that gains less ends."""
    grown = tmp_path / "tree.h5"
    grown.with_name(grown.name + ".partial").write_bytes(Path(pipeline["tree"]).read_bytes())  # the tiny tree, finished
    with h5py.File(pipeline["tree"], "r") as f:
        n = len(f["depth"])
    monkeypatch.setattr("drem_maniskill.envs.adapter.EnvAdapter.socket_geometry",
                        lambda self: (_ for _ in ()).throw(AssertionError("read the socket geometry")))
    config = _unrendered(phases={name: dict(depth=3, reach=0.5, every=4, **settings)})
    calls = _interrupt_then_resume(pipeline["expert"], grown, config, monkeypatch,
                                   lambda path, depth, chosen, kw: kw.get("group") == f"{name}_2")
    assert calls[0] == f"{name}_2" and set(calls) <= {f"{name}_2", f"{name}_3"}  # nothing of the tree it grew from
    children = settings["children"]
    with h5py.File(grown, "r") as f:
        start = int(f.attrs["start_depth"])
        origins = list(range(1, -(-start // 2) + 1, 4))  # every fourth of the first half
        assert len(origins) >= 2
        depth, parent, tcp = f["depth"][()], f["parent"][()], f["tcp_pose"][()].astype(np.float64)
        first = np.repeat([int(f[f"seeds/depth_{d}/node"][0]) for d in origins], per_origin)
        live, gone, kids, previous = np.arange(len(first)), np.zeros(len(first)), n, first
        label = np.repeat(origins, per_origin)
        for k in range(1, 4):
            if f"seeds/{name}_{k}" not in f:
                break
            group = f[f"seeds/{name}_{k}"]
            step = np.arange(kids, kids + children * len(live))
            assert np.array_equal(depth[step], np.repeat(label[live] + k, children))
            kids += len(step)
            kept, seeds = group.attrs["lineage"], group["node"][()]
            assert set(kept) <= set(live) and np.all(np.isin(seeds, step))
            along = progress(tcp[seeds], tcp[first[kept]], kept)
            np.testing.assert_allclose(along, group.attrs["progress"], atol=1e-4)
            assert np.all(along - gone[np.searchsorted(live, kept)] >= least - 1e-4)
            # The best child of its step: none of its siblings went farther.
            for lineage, seed in zip(kept, seeds):
                row = np.searchsorted(live, lineage)
                sibs = step[row * children:(row + 1) * children]
                assert seed in sibs
                assert progress(tcp[sibs], tcp[np.full(len(sibs), first[lineage])],
                                np.full(len(sibs), lineage)).max() <= along[list(kept).index(lineage)] + 1e-6
            assert np.array_equal(depth[seeds], label[kept] + k)
            assert np.array_equal(parent[seeds], previous[np.searchsorted(live, kept)])  # each on its own lineage
            live, gone, previous = kept, along, seeds
        assert kids == len(depth) and int(f.attrs[f"{name}_completed"]) == len(calls) + 1
    return grown, first[::per_origin], gone


@pytest.mark.slow
def test_twist_lineages_turn_the_part_about_the_end_effectors_axes_near_the_goal_and_end_where_it_cannot_turn(
        pipeline, tmp_path, monkeypatch):
    """Twist lineages: six per near-goal seed, about the end effector's own axes at the seed (orthonormal, each way),
    each step turning farther by at least ``min_turn`` of the controller's 0.05 rad step."""
    from drem_maniskill.pipeline.tree.phases.base import rotation_vectors
    from drem_maniskill.pipeline.tree.phases.twist import AXES_PER_ORIGIN, twist_axes

    axes = {}

    def turned(tcp, origin, lineage):
        return np.einsum("nx,nx->n", rotation_vectors(tcp[:, 3:7], origin[:, 3:7]), axes["all"][lineage])

    with h5py.File(pipeline["tree"], "r") as f:
        start = int(f.attrs["start_depth"])
        q = f["tcp_pose"][()][[int(f[f"seeds/depth_{d}/node"][0]) for d in range(1, -(-start // 2) + 1, 4)], 3:7]
    axes["all"] = twist_axes(q.astype(np.float64))
    frame = axes["all"].reshape(len(q), 3, 2, 3)
    np.testing.assert_allclose(frame[:, :, 0] @ np.swapaxes(frame[:, :, 0], 1, 2),
                               np.broadcast_to(np.eye(3), (len(q), 3, 3)), atol=1e-6)
    np.testing.assert_allclose(frame[:, :, 1], -frame[:, :, 0])
    _, _, gone = _grow_near_goal_lineages(pipeline, tmp_path, monkeypatch, "twist", dict(children=6), AXES_PER_ORIGIN,
                                          turned, least=0.25 * 0.05)
    assert len(gone) and gone.max() > 0.05  # free lineages turn more than a whole rotation step in three


@pytest.mark.slow
def test_slide_lineages_move_the_part_across_its_approach_near_the_goal_and_end_where_it_cannot_move(
        pipeline, tmp_path, monkeypatch):
    """Slide lineages: four per near-goal seed, across the approach (from the last near-goal depth's seed to the goal),
    each step moving farther by at least ``min_move`` of the step range (tiny: the whole 2 cm)."""
    from drem_maniskill.pipeline.tree.phases.slide import approach_of, slide_directions

    with h5py.File(pipeline["tree"], "r") as f:
        start = int(f.attrs["start_depth"])
        ends = f["tcp_pose"][()][[int(f[f"seeds/depth_{d}/node"][0]) for d in (-(-start // 2), 0)], :3]
    approach = approach_of(pipeline["tree"], 0.5, start)
    np.testing.assert_allclose(approach, (ends[1] - ends[0]) / np.linalg.norm(ends[1] - ends[0]), atol=1e-6)
    directions = slide_directions(approach, 4)
    np.testing.assert_allclose(directions @ approach, 0, atol=1e-9)
    np.testing.assert_allclose(np.linalg.norm(directions, axis=1), 1)
    np.testing.assert_allclose(directions[:2], -directions[2:], atol=1e-9)  # spread evenly around it
    every = np.tile(directions, (100, 1))

    def moved(tcp, origin, lineage):
        return np.einsum("nx,nx->n", tcp[:, :3] - origin[:, :3], every[lineage])

    _, _, gone = _grow_near_goal_lineages(pipeline, tmp_path, monkeypatch, "slide", dict(children=6, lineages=4), 4,
                                          moved, least=0.25 * 0.02)
    assert len(gone) and gone.max() > 0.02  # free lineages move more than a whole step's range in three


@pytest.mark.slow
def test_wander_lineages_slide_and_turn_the_part_at_once_and_end_where_it_cannot_move(pipeline, tmp_path, monkeypatch):
    """Wander lineages: four per seed, each along its own direction of sliding across the approach and turning at once,
    each step gaining at least ``min_move`` of a step (tiny: the whole 2 cm and 0.05 rad) along it."""
    from drem_maniskill.pipeline.tree.phases.base import rotation_vectors
    from drem_maniskill.pipeline.tree.phases.slide import approach_of
    from drem_maniskill.pipeline.tree.phases.wander import wander_axes, wander_directions

    with h5py.File(pipeline["tree"], "r") as f:
        start = int(f.attrs["start_depth"])
        q = f["tcp_pose"][()][[int(f[f"seeds/depth_{d}/node"][0]) for d in range(1, -(-start // 2) + 1, 4)], 3:7]
    slide, turn = wander_axes(q.astype(np.float64), approach_of(pipeline["tree"], 0.5, start),
                              wander_directions(4, _unrendered().seed))

    def gained(tcp, origin, lineage):
        return (np.einsum("nx,nx->n", tcp[:, :3] - origin[:, :3], slide[lineage]) / 0.02
                + np.einsum("nx,nx->n", rotation_vectors(tcp[:, 3:7], origin[:, 3:7]), turn[lineage]) / 0.05)

    settings = dict(children=6, lineages=4, approach_reach=None, step=1.0, turn_step=1.0)
    _, _, gone = _grow_near_goal_lineages(pipeline, tmp_path, monkeypatch, "wander", settings, 4, gained, least=0.25)
    assert len(gone) and gone.max() > 1.0  # free lineages go farther than a whole step in three


@pytest.mark.slow
def test_goal_presses_push_the_inserted_part_down_from_the_goal_one_depth_from_it(pipeline, tmp_path, monkeypatch):
    """Goal presses: children of the goal only, labelled depth 1, never seeds, pushed down on to the hole's floor
    and still in it, pressing harder than the goal's own children; a finished tree gains them by a resume that
    samples nothing else, and a second resume samples nothing."""
    # Small moves near the goal (the expert's own step), as a slow demo's tree has: the goal's own children
    # barely reach the floor 5 mm below it, and the presses' sideways and twisting actions stay as small.
    base = dict(expert_step_scale=1.0, max_depth=80)
    grown = tmp_path / "tree.h5"
    n = _finished_tree_to_grow(pipeline["expert"], grown, _unrendered(**base))
    config = _unrendered(**base, phases=dict(goal_presses=dict(count=8)))
    calls = _count_depths(monkeypatch)
    backward_sample(pipeline["expert"], str(grown), config, progress=False)
    assert calls == ["goal_press"]
    with h5py.File(grown, "r") as f:
        assert int(f.attrs["goal_press_completed"]) == 1 and len(f["depth"]) == n + 8
        depth, parent, tcp = f["depth"][()], f["parent"][()], f["tcp_pose"][()]
        tip, ft = f["tip_in_socket"][()], f["ft"][()]
        kids = np.arange(n, n + 8)
        assert np.all(depth[kids] == 1) and np.all(parent[kids] == 0) and not f["is_seed"][()][kids].any()
        own = np.nonzero((depth[:n] == 1) & (parent[:n] == 0))[0]  # the backward phase's children of the goal
        # Down on average, millimetres below the goal and its own children (whose vertical actions go either way).
        assert tcp[kids, 2].mean() < min(tcp[0, 2], tcp[own, 2].mean()) - 0.002, (tcp[kids, 2], tcp[own, 2], tcp[0, 2])
        assert np.all(tip[kids, 2] < FACE_ENTRY_HEIGHT)  # still in the hole
        force = np.linalg.norm(ft[:, -1, :3], axis=1)
        assert np.median(force[kids]) > 2 * np.median(force[own]) + 5, (force[kids], force[own])
    calls.clear()
    grown.rename(grown.with_name(grown.name + ".partial"))
    backward_sample(pipeline["expert"], str(grown), config, progress=False)
    assert calls == []


def test_a_partial_tree_resumes_with_more_workers_or_a_new_phase_but_not_with_other_children():
    """Resuming keeps what was sampled: another worker count or a larger max_depth, or a finished tree gaining a phase
    it lacked, continue it; another M or a phase changed once begun start over; a config it cannot read starts over."""
    from drem_maniskill.pipeline.tree.backward import resumable

    def header(phases=None, **core):
        config = SamplerConfig.preset("paper", **core, phases={"face": {"depth": 8}, **(phases or {})})
        return dict(config=config.to_dict(), env_id="USBInsertion-v1")

    turn, side = {"turn": {"depth": 24, "children": 16}}, {"side": {"depth": 8}}
    saved = header()
    assert resumable(saved, header(workers=2)) and resumable(saved, header(max_depth=120))
    assert resumable(saved, header(turn)) and resumable(saved, header(side))
    assert not resumable(saved, header(num_children=400))
    begun = header(turn)
    assert resumable(begun, header(turn, workers=2))
    # A phase once begun resumes only as it was.
    assert not resumable(begun, header({"turn": {"depth": 24, "children": 24}}))
    # A header's config leaves out what takes its default.
    partial = dict(config=dict(num_children=500, phases=dict(face=dict(depth=8, children=60), turn=dict(depth=0))),
                   env_id="USBInsertion-v1")
    assert resumable(partial, header()) and resumable(partial, header(side))
    assert not resumable(partial, header({"face": {"depth": 4}}))
    assert not resumable(dict(partial, env_id="PegInHole-v1"), header())
    assert not resumable(dict(config=dict(num_children=500, face_depth=8), env_id="USBInsertion-v1"), header())


def _cube_positions(tree_path: str, env_kwargs: dict) -> dict:
    """The cube's position in each depth's stored seed (the chosen child), by depth, read from its flat state."""
    from drem_maniskill.envs.adapter import adapter_for

    env = gym.make("PushCube-v1", **env_kwargs)
    try:
        env.reset(seed=0)
        adapter = adapter_for(env)
        with h5py.File(tree_path, "r") as f:
            return {int(name.split("_")[1]): adapter.unflatten(f[f"seeds/{name}/state"][()])["actors"]["cube"][0, :3]
                    .numpy() for name in f["seeds"] if name.startswith("depth_") and name != "depth_0"}
    finally:
        env.close()


@pytest.mark.slow
def test_seeds_from_the_demo_keep_a_pushed_cube_where_the_demo_had_it_and_the_papers_chain_does_not(tmp_path):
    """Random actions cannot pull a pushed cube back: the paper's chain holds the cube at the goal at every depth."""
    from drem_maniskill.experts.recording import record_expert
    from drem_maniskill.pipeline.tree.expert import load_expert
    from drem_maniskill.utils.state import state_at

    rec = record_expert("PushCube-v1", str(tmp_path / "expert"), seeds=[1000])
    expert = load_expert(rec.h5_path, 0)
    demo_cube = np.stack([np.asarray(state_at(expert.states, t)["actors"]["cube"]).reshape(-1)[:3]
                          for t in range(expert.length)])
    goal, start = demo_cube[-1], demo_cube[0]
    assert np.linalg.norm(goal - start) > 0.05  # the demo pushes the cube

    cubes = {}
    for from_demo in (False, True):
        config = _unrendered(num_children=4, max_depth=120, seeds_from_demo=from_demo)
        tree = backward_sample(rec.h5_path, str(tmp_path / f"tree_{from_demo}.h5"), config, progress=False)
        cubes[from_demo] = _cube_positions(tree, expert.env_kwargs)

    # Interrupted and resumed, a tree seeded from the demo is the same tree: the resumed seed is the demo's state
    # again, not the chosen child (whose hand is a random step, centimetres here, off the demo's). Within PhysX's
    # contact cache, which a saved state does not hold (under a millimetre).
    config = _unrendered(num_children=4, max_depth=5, seeds_from_demo=True)
    with pytest.raises(NoStartRegionError):
        backward_sample(rec.h5_path, str(tmp_path / "resumed.h5"), config, progress=False)
    config = _unrendered(num_children=4, max_depth=120, seeds_from_demo=True)
    resumed = backward_sample(rec.h5_path, str(tmp_path / "resumed.h5"), config, progress=False)
    with h5py.File(resumed, "r") as a, h5py.File(tmp_path / "tree_True.h5", "r") as b:
        assert a["tcp_pose"].shape == b["tcp_pose"].shape
        np.testing.assert_allclose(a["tcp_pose"][()], b["tcp_pose"][()], atol=2e-3)

    deepest = max(cubes[True])
    with h5py.File(tmp_path / "tree_True.h5", "r") as f:  # its nodes reach the start region, as training needs
        assert f["in_start_region"][()].any() and f["in_start_region"][f["is_seed"][()]][-1]
    # Seeded from the demo: a child at depth d is one random step from the demo's state d - 1 steps before its goal.
    for d, cube in cubes[True].items():
        t = max(expert.length - 1 - (d - 1), 0)
        assert np.linalg.norm(cube - demo_cube[t]) < 0.02, (d, cube, demo_cube[t])
    assert np.linalg.norm(cubes[True][deepest] - start) < 0.02
    # The paper's chain: the hand goes back to the start, the cube stays at the goal.
    far = cubes[False][max(cubes[False])]
    assert np.linalg.norm(far - goal) < np.linalg.norm(far - start)


def test_seeds_from_the_demo_keep_one_seed_per_depth():
    with pytest.raises(ValueError, match="seeds_from_demo keeps one seed per depth"):
        SamplerConfig(num_seeds=3, seeds_from_demo=True)
    assert SamplerConfig.from_dict({"seeds_from_demo": True}).to_dict()["seeds_from_demo"] is True
    # A tree sampled one way does not resume the other way.
    assert not SamplerConfig(seeds_from_demo=True).can_resume(SamplerConfig())


def test_a_demo_recorded_without_cameras_is_refused_with_what_to_do(tmp_path):
    # A state-mode recording keeps its observations as one flat dataset; the tree needs the demo's images.
    from drem_maniskill.experts.recording import record_expert
    from drem_maniskill.pipeline.tree.expert import load_expert

    rec = record_expert("PushCube-v1", str(tmp_path), seeds=[0], obs_mode="state", max_steps=2)
    with pytest.raises(ValueError, match="no camera images in its observations: record the expert with obs_mode='rgb'"):
        load_expert(rec.h5_path)
