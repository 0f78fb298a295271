"""The scene-poses modality (beyond the paper): what the tree stores, the model reads and the reward pays."""

from __future__ import annotations

import dataclasses

import gymnasium as gym
import h5py
import numpy as np
import pytest
import torch

import drem_maniskill  # noqa: F401
from tests.pipeline.test_stock_tasks import STOCK, stock_pipeline  # noqa: F401


def test_scene_poses_keep_poses_and_joint_positions_and_drop_velocities():
    from drem_maniskill.utils.state import scene_poses

    actor = torch.arange(13.0)[None]
    robot = torch.arange(100.0, 119.0)[None]  # root pose 7, root velocities 6, qpos 3, qvel 3
    poses = scene_poses(dict(actors=dict(cube=actor), articulations=dict(arm=robot), controller={}))
    assert poses.tolist() == [[*range(7), *range(100, 107), 113.0, 114.0, 115.0]]
    with pytest.raises(ValueError, match="no actor or articulation"):
        scene_poses(dict(controller={}))


@pytest.mark.slow
def test_the_tree_holds_the_scene_poses_of_every_node_and_of_the_demos_ends(stock_pipeline):  # noqa: F811
    from drem_maniskill.pipeline.tree.expert import load_expert
    from drem_maniskill.utils.state import scene_poses, state_at

    demo = load_expert(stock_pipeline["expert"])
    with h5py.File(stock_pipeline["tree"]) as f:
        poses, depth = torch.as_tensor(f["poses"][()]), f["depth"][()]
        first, last = torch.as_tensor(f["expert/first/poses"][()]), torch.as_tensor(f["expert/last/poses"][()])
    assert poses.shape == (len(depth), scene_poses(state_at(demo.states, 0)).shape[1])
    torch.testing.assert_close(first, scene_poses(state_at(demo.states, 0))[0])
    torch.testing.assert_close(last, scene_poses(state_at(demo.states, demo.length - 1))[0])
    torch.testing.assert_close(poses[depth == 0][0], last)  # the root is the demo's goal
    assert (poses.std(0) > 1e-3).sum() >= 3  # the children moved the arm's joints


@pytest.mark.slow
def test_a_model_reading_poses_pays_for_where_the_objects_are(stock_pipeline, tmp_path):  # noqa: F811
    """A poses-only reward trained on the tree: its statistics are the tree's, and moving the peg alone changes
    what it pays (a camera-free reward that reads the objects)."""
    from mani_skill.utils.structs import Pose

    from drem_maniskill.drem.model import ModelConfig
    from drem_maniskill.drem.reward import DREMReward
    from drem_maniskill.pipeline.dataset import TreeDataset
    from drem_maniskill.pipeline.train_reward import TrainConfig, train_reward

    config = TrainConfig.preset("tiny", iterations=6, model=ModelConfig(image_size=64, modalities=("poses",)))
    checkpoint = train_reward(stock_pipeline["tree"], str(tmp_path / "reward"), config, progress=False)
    env = gym.make(STOCK, obs_mode="state", control_mode="pd_ee_delta_pose")
    try:
        reward = DREMReward.from_checkpoint(checkpoint, env)
        data = TreeDataset(stock_pipeline["tree"], reward.model.config)
        torch.testing.assert_close(reward.model.poses_mean, data.poses.mean(0))
        assert reward.camera_uids == [] and reward.model.config.poses_size == data.poses.shape[1]
        env.reset(seed=3)
        before = reward.reward(env.unwrapped, None)
        peg = env.unwrapped.peg
        peg.set_pose(Pose.create_from_pq(p=peg.pose.p + torch.tensor([0.0, 0.1, 0.0]), q=peg.pose.q))
        after = reward.reward(env.unwrapped, None)
        assert before.shape == (1,) and torch.isfinite(after).all() and not torch.allclose(before, after)
    finally:
        env.close()


@pytest.mark.slow
def test_a_poses_model_needs_a_tree_with_poses(stock_pipeline, tmp_path):  # noqa: F811
    import shutil

    from drem_maniskill.drem.model import ModelConfig
    from drem_maniskill.pipeline.dataset import TreeDataset

    old = tmp_path / "tree.h5"
    shutil.copy(stock_pipeline["tree"], old)
    with h5py.File(old, "a") as f:
        del f["poses"]
    with pytest.raises(ValueError, match="holds no scene poses.*re-sample"):
        TreeDataset(str(old), ModelConfig(image_size=64, modalities=("fixed", "poses")))


@pytest.mark.slow
def test_a_tree_sampled_without_images_holds_poses_and_trains_only_a_camera_free_model(tmp_path):
    from drem_maniskill.drem.model import ModelConfig
    from drem_maniskill.experts.recording import record_expert
    from drem_maniskill.pipeline import SamplerConfig, backward_sample
    from drem_maniskill.pipeline.dataset import TreeDataset, dataset_modalities

    rec = record_expert("PushCube-v1", str(tmp_path / "expert"), seeds=[1000])
    config = SamplerConfig.preset("tiny", num_children=4, max_depth=120, images=False)
    tree = backward_sample(rec.h5_path, str(tmp_path / "tree.h5"), config, progress=False)
    rendered = backward_sample(rec.h5_path, str(tmp_path / "rendered.h5"), dataclasses.replace(config, images=True),
                               progress=False)
    with h5py.File(tree) as f, h5py.File(rendered) as g:
        assert "fixed_rgb" not in f and f["poses"].shape[0] == f["depth"].shape[0] > 4
        assert "expert/last/fixed_rgb" in f  # the demo's own images stay
        # Rendering changes nothing else: the same nodes, depths and poses as the tree sampled with images.
        for key in ("depth", "parent", "poses", "tcp_pose", "in_start_region"):
            assert np.array_equal(f[key][()], g[key][()]), key
    assert dataset_modalities(tree) == ("poses",)
    assert TreeDataset(tree, ModelConfig(image_size=64, modalities=("poses",))).poses.shape[0] > 4
    with pytest.raises(ValueError, match="sampled without images.*--modalities poses"):
        TreeDataset(tree, ModelConfig(image_size=64, modalities=("fixed", "poses")))


def test_a_recipe_that_samples_no_images_cannot_train_a_camera_model():
    from drem_maniskill.pipeline.recipe import RecipeError, load_recipe

    recipe = {"sampler": {"images": False}, "train": {"model": {"modalities": ["fixed", "poses"]}}}
    with pytest.raises(RecipeError, match=r"images = false samples no camera images, but the models read \['fixed'\]"):
        load_recipe("PushCube-v1", recipe=recipe)
    assert load_recipe("PushCube-v1", recipe={**recipe, "train": {"model": {"modalities": ["poses"]}}})


def test_a_round_that_found_no_negatives_costs_a_poses_reward_nothing(tmp_path):
    """A policy round whose policy reached no well-paid failure writes an empty negatives file without poses; what a
    poses reward pays it is empty, and a round that found some is paid one value per row."""
    from drem_maniskill.drem.checkpoint import load_checkpoint
    from drem_maniskill.drem.reward import DREMReward
    from drem_maniskill.pipeline.negatives import paid_on_negatives, write_negatives
    from tests.conftest import tiny_checkpoint

    reward = DREMReward(*load_checkpoint(tiny_checkpoint(tmp_path / "r.pt", STOCK, ("poses",), (), poses_size=5)))
    write_negatives(tmp_path / "none.h5", [], 9, [], False)
    assert paid_on_negatives(reward, tmp_path / "none.h5").shape == (0,)
    poses = torch.randn(3, 5, generator=torch.Generator().manual_seed(0))
    rows = [({"poses": poses[t:t + 1]}, 0.9, 7, t) for t in range(3)]
    write_negatives(tmp_path / "some.h5", rows, 9, [], False)
    paid = paid_on_negatives(reward, tmp_path / "some.h5")
    with torch.no_grad():
        np.testing.assert_allclose(paid, reward({"poses": poses}).numpy(), rtol=1e-5)


def test_relative_poses_add_each_actor_pairs_position_difference_which_a_shared_shift_leaves_alone():
    from drem_maniskill.drem.model import DREMModel, ModelConfig

    config = ModelConfig(modalities=("poses",), poses_size=7 * 3 + 4, poses_relative=True, poses_actors=3)
    model = DREMModel(config)
    poses = torch.randn(2, config.poses_size, generator=torch.Generator().manual_seed(0))
    features = model.prepare({"poses": poses})["poses"]
    p = poses[:, :21].reshape(2, 3, 7)[..., :3]
    pairs = torch.cat([p[:, 0] - p[:, 1], p[:, 0] - p[:, 2], p[:, 1] - p[:, 2]], dim=1)
    assert features.shape == (2, 25 + 9) and model.poses_mean.shape == (34,)
    torch.testing.assert_close(features[:, 25:], pairs)  # unit statistics until set_poses_stats
    shifted = poses.clone()
    shifted[:, [0, 7, 14]] += 0.3  # every actor 30 cm along x
    torch.testing.assert_close(model.prepare({"poses": shifted})["poses"][:, 25:], pairs)
    assert not torch.allclose(model.prepare({"poses": shifted})["poses"][:, :25], features[:, :25])
    with pytest.raises(ValueError, match="poses_relative needs at least two actors"):
        DREMModel(ModelConfig(modalities=("poses",), poses_size=25, poses_relative=True, poses_actors=1))


@pytest.mark.slow
def test_a_relative_poses_reward_reads_its_actor_count_from_the_trees_env(stock_pipeline, tmp_path):  # noqa: F811
    from drem_maniskill.drem.model import ModelConfig
    from drem_maniskill.drem.reward import DREMReward
    from drem_maniskill.pipeline.train_reward import TrainConfig, train_reward

    model = ModelConfig(image_size=64, modalities=("poses",), poses_relative=True)
    checkpoint = train_reward(stock_pipeline["tree"], str(tmp_path / "reward"), TrainConfig.preset(
        "tiny", iterations=4, model=model), progress=False)
    env = gym.make(STOCK, obs_mode="state", control_mode="pd_ee_delta_pose")
    try:
        reward = DREMReward.from_checkpoint(checkpoint, env)
        env.reset(seed=3)
        actors = len(env.unwrapped.get_state_dict()["actors"])
        assert reward.model.config.poses_actors == actors >= 2
        assert reward.model.poses_mean.shape[0] == reward.model.config.poses_size + 3 * actors * (actors - 1) // 2
        assert torch.isfinite(reward.reward(env.unwrapped, None)).all()
    finally:
        env.close()
