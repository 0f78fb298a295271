"""The DREM chain on ManiSkill's own PegInsertionSide-v1.

Its cameras, no F/T, the wrapper, the alias, the examination.
"""

from __future__ import annotations

import json

import gymnasium as gym
import h5py
import numpy as np
import pytest
import torch

import drem_maniskill  # noqa: F401

STOCK = "PegInsertionSide-v1"


@pytest.fixture(scope="module")
def stock_pipeline(tmp_path_factory):
    from drem_maniskill.drem.model import ModelConfig
    from drem_maniskill.experts.recording import record_expert
    from drem_maniskill.pipeline.dataset import dataset_modalities
    from drem_maniskill.pipeline import SamplerConfig, backward_sample
    from drem_maniskill.pipeline.train_reward import TrainConfig, train_reward

    root = tmp_path_factory.mktemp("stock")
    def lift(obs):  # six steps up (about 10 cm) with the gripper open: a short stand-in for an expert
        return torch.tensor([[0.0, 0.0, 0.3, 0.0, 0.0, 0.0, 1.0]])

    rec = record_expert(STOCK, str(root / "expert"), seeds=[0], policy=lift, max_steps=6)
    config = SamplerConfig.preset("tiny", num_children=6, max_depth=15, start_radius=0.05)
    tree = backward_sample(rec.h5_path, str(root / "tree.h5"), config, progress=False)
    modalities = dataset_modalities(tree)
    train = TrainConfig.preset("tiny", iterations=6, model=ModelConfig(image_size=64, modalities=modalities))
    checkpoint = train_reward(tree, str(root / "reward"), train, progress=False)
    return dict(expert=rec.h5_path, tree=tree, modalities=modalities, checkpoint=checkpoint)


@pytest.mark.slow
def test_stock_tree_uses_the_tasks_cameras_and_no_ft(stock_pipeline):
    with h5py.File(stock_pipeline["tree"]) as f:
        header = json.loads(f.attrs["header"])
        assert header["camera_map"] == {"fixed": "base_camera", "wrist": "hand_camera"}
        assert header["has_ft"] is False and header["action_dim"] == 7
        assert f["fixed_rgb"].shape[1:] == (128, 128, 3) and f["wrist_rgb"].dtype == np.uint8
        assert f["in_start_region"][()].any() and f["depth"][()].max() >= 1
        # The start region is reached by the last seed, not before (the loop stops there).
        seeds = f["in_start_region"][()][f["is_seed"][()]]
        assert seeds[-1] and not seeds[:-1].any()
    assert stock_pipeline["modalities"] == ("fixed", "wrist")


@pytest.mark.slow
def test_stock_checkpoint_drives_the_wrapper(stock_pipeline):
    from drem_maniskill.drem.checkpoint import CheckpointError, load_checkpoint
    from drem_maniskill.drem.wrapper import DREMRewardWrapper

    header, _ = load_checkpoint(stock_pipeline["checkpoint"])
    assert header["env_id"] == STOCK and header["camera_uids"] == ["base_camera", "hand_camera"]
    stock_env = gym.make(STOCK, obs_mode="state", control_mode="pd_ee_delta_pose")
    env = DREMRewardWrapper(stock_env, stock_pipeline["checkpoint"])
    try:
        env.reset(seed=1)
        _, reward, _, _, info = env.step(torch.zeros(1, 7))
        assert reward.shape == (1,) and torch.isfinite(reward).all()
        assert "original_reward" in info and not torch.equal(reward, info["original_reward"])
    finally:
        env.close()
    # A checkpoint of the stock task does not fit our task.
    with pytest.raises(CheckpointError, match="PegInsertionSide-v1"):
        DREMRewardWrapper(gym.make("PegInHole-v1"), stock_pipeline["checkpoint"])


@pytest.mark.slow
def test_a_tree_of_another_task_cannot_join_a_forest(stock_pipeline, pipeline):
    from drem_maniskill.drem.model import ModelConfig
    from drem_maniskill.pipeline.dataset import TreeDataset

    data = TreeDataset(stock_pipeline["tree"], ModelConfig(image_size=64, modalities=stock_pipeline["modalities"]))
    with pytest.raises(ValueError, match="was sampled on PegInHole-v1, the first tree on PegInsertionSide-v1"):
        data.add_trees([pipeline["tree"]], ModelConfig(image_size=64, modalities=stock_pipeline["modalities"]))


@pytest.mark.slow
def test_training_with_ft_on_a_tree_without_it_is_a_clear_error(stock_pipeline, tmp_path):
    from drem_maniskill.drem.model import ModelConfig
    from drem_maniskill.pipeline.train_reward import TrainConfig, train_reward

    config = TrainConfig.preset("tiny", iterations=1, model=ModelConfig(image_size=64))
    with pytest.raises(ValueError, match="no wrist F/T sensor.*--modalities fixed wrist"):
        train_reward(stock_pipeline["tree"], str(tmp_path / "r"), config, progress=False)


@pytest.mark.slow
def test_register_drem_env_makes_drem_the_stock_tasks_default(stock_pipeline, tmp_path):
    from mani_skill.vector.wrappers.gymnasium import ManiSkillVectorEnv

    from drem_maniskill import register_drem_env
    from drem_maniskill.drem.wrapper import DREMRewardWrapper

    env_id = register_drem_env(STOCK, stock_pipeline["checkpoint"])
    assert env_id == "PegInsertionSide-DREM-v1"
    kwargs = dict(obs_mode="state", control_mode="pd_ee_delta_pose")
    alias = ManiSkillVectorEnv(gym.make(env_id, **kwargs), auto_reset=False, ignore_terminations=True)
    # The id pays R - 1 (drem_form "shifted", safe where success ends the episode), as the wrapper with that form.
    wrapped = DREMRewardWrapper(gym.make(STOCK, **kwargs), stock_pipeline["checkpoint"], form="shifted")
    try:
        assert alias.unwrapped.reward_mode == "drem"
        rewards = []
        for env in (alias, wrapped):
            env.reset(seed=2)
            _, reward, _, _, info = env.step(torch.tensor([[0.2, 0.0, -0.2, 0.0, 0.0, 0.0, 1.0]]))
            rewards.append(reward)
            assert "success" in info
        # The registered id and the wrapper give the same DREM reward for the same step.
        torch.testing.assert_close(rewards[0].float(), rewards[1].float(), atol=1e-4, rtol=1e-4)
    finally:
        alias.close(), wrapped.close()
    with pytest.raises(ValueError, match="trained on 'PegInsertionSide-v1', not 'PlugCharger-v1'"):
        register_drem_env("PlugCharger-v1", stock_pipeline["checkpoint"])


@pytest.mark.slow
def test_examine_a_stock_task_against_its_normalized_dense(stock_pipeline, tmp_path):
    """On PegInsertionSide-v1 the examination runs the stock expert, its noisy version and random,
    and sets DREM beside ManiSkill's own normalized_dense, step by step."""
    from PIL import Image

    from drem_maniskill.evaluate.examine import STOCK_EXAMINATION, examine

    result = examine(STOCK, stock_pipeline["checkpoint"], seeds=[0], out_dir=str(tmp_path))
    assert tuple(result["curves"]) == STOCK_EXAMINATION
    assert result["success_rate"]["direct_success"] == 1.0 and result["success_rate"]["random"] == 0.0
    assert result["expert_success_rate"] == 1.0
    for name, runs in result["curves"].items():
        assert len(runs[0]) == len(result["dense_curves"][name][0]) == 100  # the stock horizon, no early stop
    rho = result["spearman_with_normalized_dense"]
    assert rho is not None and -1.0 <= rho <= 1.0
    saved = json.loads((tmp_path / "quality.json").read_text())
    assert saved["spearman_with_normalized_dense"] == rho
    width, height = Image.open(tmp_path / "examination.png").size
    assert width > 1.5 * height  # two panels: DREM and normalized_dense
