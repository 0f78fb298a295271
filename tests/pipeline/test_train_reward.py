"""Reward training: exact resume after an interruption, a short training that orders the tree, degenerate rewards."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from scipy.stats import spearmanr

from drem_maniskill.drem.checkpoint import CheckpointError, load_checkpoint, save_checkpoint
from drem_maniskill.drem.model import INITS, DegenerateRewardError, DREMModel, ModelConfig, cosine_distance
from drem_maniskill.drem.reward import DREMReward
from drem_maniskill.pipeline.dataset import TreeDataset
from drem_maniskill.pipeline.train_reward import TrainConfig, train_reward
from tests.conftest import tiny_checkpoint

# About 30 s here; PyTorch's init reaches Spearman 0.65-0.74 or a degenerate normaliser with the same budget.
ORDER_TRAINING = dict(iterations=300, pairs_per_batch=16)


@pytest.mark.slow
def test_training_resumes_exactly(pipeline, tmp_path):
    def run(folder, iterations):
        config = TrainConfig.preset("tiny", iterations=iterations, save_every=6)
        return train_reward(pipeline["tree"], str(tmp_path / folder), config, progress=False)

    straight = run("a", 12)
    run("b", 6)
    resumed = run("b", 12)
    wa, wb = load_checkpoint(straight)[1], load_checkpoint(resumed)[1]
    for key in wa:
        torch.testing.assert_close(wa[key], wb[key], atol=1e-5, rtol=1e-4)
    assert (tmp_path / "a" / "tb").exists()


def _latents(model: DREMModel, data: TreeDataset) -> torch.Tensor:
    """``h`` of every node of ``data``, 64 nodes at a time."""
    with torch.no_grad():
        return torch.cat([model.encode(model.prepare(data.batch(part)))
                          for part in torch.arange(len(data.depth)).split(64)])


def _depth_order(checkpoint: str, tree: str) -> tuple[float, float]:
    """Spearman(depth, d(h, h_G)) over every node of ``tree``, and ``d(h_0, h_G)``, measured from the file alone."""
    header, weights = load_checkpoint(checkpoint)
    model = DREMModel(ModelConfig.from_dict(header["model"]))
    model.load_state_dict({k[len("model."):]: v for k, v in weights.items() if k.startswith("model.")})
    model.eval()
    data = TreeDataset(tree, model.config)
    h = _latents(model, data)
    dist = cosine_distance(h, weights["h_goal"][None]).numpy()
    normaliser = float(cosine_distance(weights["h_start"][None], weights["h_goal"][None])[0])
    return float(spearmanr(data.depth.numpy(), dist).correlation), normaliser


@pytest.mark.slow
def test_a_short_training_orders_the_tree_by_depth(pipeline, tmp_path):
    config = TrainConfig.preset("tiny", **ORDER_TRAINING, model=ModelConfig(image_size=64, init="kaiming"))
    checkpoint = train_reward(pipeline["tree"], str(tmp_path / "kaiming"), config, progress=False)
    order, normaliser = _depth_order(checkpoint, pipeline["tree"])
    assert order >= 0.9, f"latent distance to the goal does not follow depth: Spearman {order:.3f}"
    assert normaliser >= 0.1, f"d(h_0, h_G) = {normaliser:.3g}: start and goal embed almost alike"
    fit = load_checkpoint(checkpoint)[0]["fit"]
    assert fit["tree_order"] == pytest.approx(order, abs=0.05) and fit["normaliser"] == pytest.approx(normaliser)


@pytest.mark.parametrize("seed", [0, 1])
def test_pytorchs_init_embeds_every_node_alike_and_kaiming_does_not(pipeline, seed):
    """Why ``init="kaiming"``: under PyTorch's layer defaults the image encoders' outputs barely depend on the image,
    so every latent points the same way and the triplet loss has no distance to start from."""
    spread = {}
    for init in INITS:
        torch.manual_seed(seed)
        config = ModelConfig(image_size=64, init=init)
        model = DREMModel(config).eval()
        h = torch.nn.functional.normalize(_latents(model, TreeDataset(pipeline["tree"], config)), dim=1)
        spread[init] = float((1 - h @ h.T).mean())  # mean cosine distance over every pair of nodes
    # Measured: PyTorch's 0.008 against kaiming's 0.33-0.36 on this tree, 0.0002 against 0.08-0.13 on the demo's.
    assert spread["torch"] < 0.1 * spread["kaiming"], spread


def test_a_checkpoint_with_a_degenerate_normaliser_is_refused_at_load(tmp_path):
    path = tiny_checkpoint(tmp_path / "c.pt", "PegInHole-v1")
    header, weights = load_checkpoint(path)
    weights = dict(weights)
    weights["h_start"] = weights["h_goal"] * 3.0 + 1e-6  # same direction: d(h_0, h_G) ~ 0
    save_checkpoint(str(tmp_path / "flat.pt"), header, weights)
    with pytest.raises(CheckpointError, match=r"degenerate: d\(h\(s_0\), h\(s_G\)\) = .* below 0.01"):
        DREMReward.from_checkpoint(str(tmp_path / "flat.pt"))
    DREMReward.from_checkpoint(path)  # the same weights with distinct start and goal load


def test_training_refuses_to_export_a_degenerate_reward(pipeline, tmp_path, monkeypatch):
    from drem_maniskill.pipeline.train_reward import export_reward

    config = TrainConfig.preset("tiny")
    model = DREMModel(config.model)
    # An encoder whose output ignores its input: the start and the goal embed alike.
    monkeypatch.setattr(model, "encode", lambda inputs: torch.ones(len(next(iter(inputs.values()))), 4))
    with pytest.raises(DegenerateRewardError, match="degenerate"):
        export_reward(model, TreeDataset(pipeline["tree"], config.model), config, tmp_path / "drem.pt")
    assert not (tmp_path / "drem.pt").exists()


def test_shipped_checkpoints_have_a_usable_normaliser():
    from pathlib import Path

    paths = sorted((Path(__file__).resolve().parents[2] / "rewards").glob("*/*.pt"))
    assert paths
    for path in paths:
        weights = load_checkpoint(path)[1]
        d = float(cosine_distance(weights["h_start"][None], weights["h_goal"][None])[0])
        assert np.isfinite(d) and d > 1.0, str(path)
