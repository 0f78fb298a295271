"""DREMReward: Eq. 2's normalisation by the expert, and the drem reward mode in every obs mode."""

from __future__ import annotations

import gymnasium as gym
import h5py
import numpy as np
import pytest
import torch

from drem_maniskill.drem.checkpoint import (
    CheckpointError,
    load_checkpoint,
)
from drem_maniskill.drem.reward import DREMReward


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
    # Eq. 2 on a batch: R = 1 - d(h, h_G) / d(h_0, h_G), with the cosine distance. A 20-iteration
    # model can put h(s_0) and h(s_G) almost on one line (a cosine distance near 1e-6), where float
    # rounding is amplified a millionfold: the arithmetic is checked with h(s_0) moved opposite h(s_G)
    # (the fast path notices the edit and recomputes its constants).
    from drem_maniskill.drem.model import cosine_distance

    reward.h_start.copy_(-reward.h_goal)
    batch = {k: torch.cat([first[k], last[k], first[k]]) for k in first}
    batch["ft"][2] += 5.0
    r = reward(batch)
    assert r.shape == (3,) and not r.requires_grad
    h = reward.embed(batch)
    expected = 1 - cosine_distance(h, reward.h_goal[None]) / cosine_distance(reward.h_start[None], reward.h_goal[None])
    torch.testing.assert_close(r, expected, atol=1e-5, rtol=1e-5)
    assert r[1].item() == pytest.approx(1.0, abs=1e-4)  # the goal's own observation
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
