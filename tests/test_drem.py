"""The DREM pipeline at a tiny scale: model, checkpoints, sampler, trainer, reward, reward_mode."""

from __future__ import annotations

import pickle

import gymnasium as gym
import h5py
import numpy as np
import pytest
import torch

from drem_maniskill.drem.checkpoint import CheckpointError, check_compatible, load_checkpoint, save_checkpoint
from drem_maniskill.drem.model import DREMModel, ModelConfig
from drem_maniskill.drem.reward import DREMReward
from drem_maniskill.pipeline.sampling import NoStartRegionError, SamplerConfig, backward_sample
from drem_maniskill.pipeline.train_reward import TrainConfig, train_reward
from drem_maniskill.experts.recording import record_expert


@pytest.fixture(scope="session")
def pipeline(tmp_path_factory):
    """Record one expert episode, sample a tiny tree, train a tiny reward (about a minute)."""
    root = tmp_path_factory.mktemp("drem")
    rec = record_expert("PegInHole-v1", str(root / "expert"), seeds=[5], obs_mode="rgb")
    tree = backward_sample(rec.h5_path, str(root / "tree.h5"), SamplerConfig.preset("tiny"), progress=False)
    ckpt = train_reward(tree, str(root / "reward"), TrainConfig.preset("tiny"), progress=False)
    return dict(root=root, expert=rec.h5_path, tree=tree, checkpoint=ckpt)


def _batch(b, size=128, modalities=("fixed", "wrist", "ft")):
    out = {c: torch.randint(0, 255, (b, size, size, 3), dtype=torch.uint8) for c in modalities if c != "ft"}
    out["ft"] = torch.randn(b, 8, 6)
    return out


@pytest.mark.parametrize("modalities", [("fixed", "wrist", "ft"), ("fixed", "wrist"), ("wrist", "ft")])
def test_model_shapes(modalities):
    model = DREMModel(ModelConfig(modalities=modalities))
    h, recon, inputs = model(_batch(3, modalities=modalities))
    assert h.shape == (3, 128)
    for c in model.config.cameras:
        assert recon[c].shape == (3, 3, 128, 128)
    assert ("ft" in recon) == ("ft" in modalities)
    if "ft" in recon:
        assert recon["ft"].shape == (3, 8, 6)
    # Paper's architecture: 6 conv layers per image encoder, 4 causal F/T layers.
    enc = next(iter(model.image_encoders.values()))
    assert sum(isinstance(m, torch.nn.Conv2d) for m in enc.modules()) == 6
    dec = next(iter(model.image_decoders.values()))
    assert sum(isinstance(m, torch.nn.ConvTranspose2d) for m in dec.modules()) == 7


def test_model_resizes_other_image_sizes():
    model = DREMModel(ModelConfig(image_size=64)).eval()
    big = _batch(2, size=128)
    small = {k: (torch.nn.functional.interpolate(v.permute(0, 3, 1, 2).float(), size=(64, 64), mode="area").round().to(torch.uint8).permute(0, 2, 3, 1)
                 if k != "ft" else v) for k, v in big.items()}
    with torch.no_grad():
        h_big = model.encode(model.prepare(big))
        h_small = model.encode(model.prepare(small))
    torch.testing.assert_close(h_big, h_small, atol=0.05, rtol=0.05)


def test_bad_model_config_is_a_clear_error():
    with pytest.raises(ValueError, match="modalities"):
        ModelConfig(modalities=("fixed", "sonar"))
    with pytest.raises(ValueError, match="multiple of 64"):
        ModelConfig(image_size=100)


def test_checkpoint_round_trip_and_errors(tmp_path):
    path = save_checkpoint(str(tmp_path / "c.pt"), {"env_id": "X-v1"}, {"w": torch.ones(3)})
    header, weights = load_checkpoint(path)
    assert header == {"env_id": "X-v1"} and torch.equal(weights["w"], torch.ones(3))
    with pytest.raises(CheckpointError, match="not found"):
        load_checkpoint(str(tmp_path / "missing.pt"))
    data = open(path, "rb").read()
    (tmp_path / "cut.pt").write_bytes(data[: len(data) // 2])
    with pytest.raises(CheckpointError, match="truncated or corrupt"):
        load_checkpoint(str(tmp_path / "cut.pt"))
    torch.save({"format": "other"}, tmp_path / "other.pt")
    with pytest.raises(CheckpointError, match="not a DREM reward checkpoint"):
        load_checkpoint(str(tmp_path / "other.pt"))


class _Evil:
    def __reduce__(self):
        return (exec, ("import pathlib; pathlib.Path('PWNED').write_text('x')",))


def test_checkpoint_never_executes_code(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    with open(tmp_path / "evil.pt", "wb") as f:
        pickle.dump({"format": "drem-maniskill-reward/1", "header": "{}", "weights": _Evil()}, f)
    with pytest.raises(CheckpointError):
        load_checkpoint(str(tmp_path / "evil.pt"))
    assert not (tmp_path / "PWNED").exists()


def test_compatibility_check_names_every_difference():
    header = dict(env_id="PegInHole-v1", camera_uids=["fixed_camera", "wrist_camera"], modalities=["fixed", "wrist", "ft"], ft_history=8)
    check_compatible(header, "PegInHole-v1", {"fixed_camera": (128, 128), "wrist_camera": (128, 128)}, 8)
    with pytest.raises(CheckpointError) as err:
        check_compatible(header, "USBInsertion-v1", {"fixed_camera": (128, 128)}, 4)
    msg = str(err.value)
    assert "'PegInHole-v1'" in msg and "'USBInsertion-v1'" in msg
    assert "'wrist_camera'" in msg and "history of 8" in msg and "gives 4" in msg
    with pytest.raises(CheckpointError, match="F/T history, which this env does not provide"):
        check_compatible(header, "PegInHole-v1", {"fixed_camera": (1, 1), "wrist_camera": (1, 1)}, None)


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
def test_sampler_fails_clearly_then_resumes(pipeline, tmp_path):
    out = tmp_path / "tree.h5"
    with pytest.raises(NoStartRegionError, match="max_depth=3"):
        backward_sample(pipeline["expert"], str(out), SamplerConfig.preset("tiny", max_depth=3), progress=False)
    partial = out.with_name(out.name + ".partial")
    with h5py.File(partial, "r") as f:
        assert f.attrs["completed_depth"] == 3
    # The interrupted run resumes from depth 3; with max_depth raised it completes like a fresh run.
    backward_sample(pipeline["expert"], str(out), SamplerConfig.preset("tiny", max_depth=3 + 37), progress=False)
    assert not partial.exists()
    with h5py.File(out, "r") as a, h5py.File(pipeline["tree"], "r") as b:
        np.testing.assert_array_equal(a["depth"][()], b["depth"][()])
        np.testing.assert_allclose(a["tcp_pose"][()], b["tcp_pose"][()], atol=1e-4)


@pytest.mark.slow
def test_dataset_without_start_region_is_rejected(pipeline, tmp_path):
    bad = tmp_path / "bad.h5"
    bad.write_bytes(open(pipeline["tree"], "rb").read())
    with h5py.File(bad, "a") as f:
        f["in_start_region"][...] = False
    with pytest.raises(ValueError, match="no start-region states"):
        train_reward(str(bad), str(tmp_path / "r"), TrainConfig.preset("tiny"), progress=False)


@pytest.mark.slow
def test_training_resumes_exactly(pipeline, tmp_path):
    straight = train_reward(pipeline["tree"], str(tmp_path / "a"), TrainConfig.preset("tiny", iterations=12, save_every=6), progress=False)
    train_reward(pipeline["tree"], str(tmp_path / "b"), TrainConfig.preset("tiny", iterations=6, save_every=6), progress=False)
    resumed = train_reward(pipeline["tree"], str(tmp_path / "b"), TrainConfig.preset("tiny", iterations=12, save_every=6), progress=False)
    wa, wb = load_checkpoint(straight)[1], load_checkpoint(resumed)[1]
    for key in wa:
        torch.testing.assert_close(wa[key], wb[key], atol=1e-5, rtol=1e-4)
    assert (tmp_path / "a" / "tb").exists()


@pytest.mark.slow
def test_reward_is_normalised_by_the_expert(pipeline):
    reward = DREMReward.from_checkpoint(pipeline["checkpoint"])
    header, _ = load_checkpoint(pipeline["checkpoint"])
    assert header["env_id"] == "PegInHole-v1" and header["image_size"] == 64
    assert header["camera_uids"] == ["fixed_camera", "wrist_camera"] and header["ft_history"] == 8
    with h5py.File(pipeline["tree"], "r") as f:
        first = {k: torch.as_tensor(f[f"expert/first/{k}_rgb"][()])[None] for k in ("fixed", "wrist")}
        first["ft"] = torch.as_tensor(f["expert/first/ft"][()])[None]
        last = {k: torch.as_tensor(f[f"expert/last/{k}_rgb"][()])[None] for k in ("fixed", "wrist")}
        last["ft"] = torch.as_tensor(f["expert/last/ft"][()])[None]
    # h(s_0) and h(s_G) in the checkpoint are the embeddings of the expert's first and last obs.
    torch.testing.assert_close(reward.embed(first)[0], reward.h_start, atol=1e-4, rtol=1e-4)
    torch.testing.assert_close(reward.embed(last)[0], reward.h_goal, atol=1e-4, rtol=1e-4)
    # Eq. 2 on a batch: R = 1 - d(h, h_G) / d(h_0, h_G), with the cosine distance.
    batch = {k: torch.cat([first[k], last[k], first[k]]) for k in first}
    batch["ft"][2] += 5.0
    r = reward(batch)
    assert r.shape == (3,) and not r.requires_grad
    from drem_maniskill.drem.model import cosine_distance

    h = reward.embed(batch)
    expected = 1 - cosine_distance(h, reward.h_goal[None]) / cosine_distance(reward.h_start[None], reward.h_goal[None])
    torch.testing.assert_close(r, expected)
    assert r[2].item() != r[0].item()  # the F/T history is an input


@pytest.mark.slow
def test_reward_mode_drem_in_every_obs_mode(pipeline):
    from drem_maniskill.experts import get_policy

    results = {}
    for obs_mode in ("rgb", "state", "none"):
        env = gym.make("PegInHole-v1", obs_mode=obs_mode, reward_mode="drem", drem_checkpoint=pipeline["checkpoint"])
        try:
            policy = get_policy("expert", env)
            obs, _ = env.reset(seed=3)
            rewards = []
            for _ in range(4):
                obs, r, _, _, info = env.step(policy(obs))
                assert r.shape == (1,)
                rewards.append(r.item())
            results[obs_mode] = rewards
            assert "success" in info
        finally:
            env.close()
    np.testing.assert_allclose(results["rgb"], results["state"], atol=1e-4)
    np.testing.assert_allclose(results["rgb"], results["none"], atol=1e-4)
    with pytest.raises(CheckpointError, match="USBInsertion-v1"):
        gym.make("USBInsertion-v1", reward_mode="drem", drem_checkpoint=pipeline["checkpoint"])


@pytest.mark.slow
def test_wrapper_replaces_the_reward_and_keeps_the_original(pipeline):
    from drem_maniskill.drem.wrapper import DREMRewardWrapper

    inner = gym.make("PegInHole-v1", obs_mode="state", reward_mode="normalized_dense")
    reference = gym.make("PegInHole-v1", obs_mode="rgb", reward_mode="drem", drem_checkpoint=pipeline["checkpoint"])
    env = DREMRewardWrapper(inner, pipeline["checkpoint"])
    try:
        env.reset(seed=9)
        reference.reset(seed=9)
        action = torch.tensor([[0.2, -0.1, -0.4, 0.0, 0.0, 0.1]])
        _, reward, _, _, info = env.step(action)
        _, expected, _, _, _ = reference.step(action)
        torch.testing.assert_close(reward, expected, atol=1e-4, rtol=0)
        assert 0 < info["original_reward"].item() <= 1  # the task's normalized_dense
    finally:
        env.close()
        reference.close()


@pytest.mark.parametrize("task", ["PegInHole-v1", "USBInsertion-v1"])
def test_shipped_checkpoints_load_by_default(task):
    env = gym.make(task, obs_mode="state", reward_mode="drem")
    try:
        header = env.unwrapped.drem_reward.header
        assert header["env_id"] == task and header["modalities"] == ["fixed", "wrist", "ft"]
        env.reset(seed=0)
        _, reward, *_ = env.step(torch.zeros(1, 6))
        # At the start of an episode the part is far from the goal: low progress.
        assert reward.shape == (1,) and reward.item() < 0.5
    finally:
        env.close()


@pytest.mark.parametrize("task", ["PegInHole-v1", "USBInsertion-v1"])
def test_shipped_expert_demos_reach_the_goal(task):
    from pathlib import Path

    from drem_maniskill.pipeline.sampling import load_expert
    from drem_maniskill.utils.state import broadcast_state, state_at

    expert = load_expert(str(Path(__file__).parents[1] / "tasks" / task / "expert.h5"))
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
