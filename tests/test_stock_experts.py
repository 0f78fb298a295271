"""Scripted experts for ManiSkill's own PegInsertionSide-v1 and PlugCharger-v1 (no motion planner).

They are what ``drem-maniskill record-expert --task <stock id>`` rolls out, so DREM's pipeline
starts from a demo on those tasks as it does on ours.
"""

from __future__ import annotations

import json

import gymnasium as gym
import h5py
import numpy as np
import pytest
import torch

import drem_maniskill  # noqa: F401
from drem_maniskill.experts import get_policy, success_rate
from drem_maniskill.experts.stock import PegInsertionSideExpert, PlugChargerExpert


@pytest.mark.parametrize("env_id", ["PegInsertionSide-v1", "PlugCharger-v1"])
def test_stock_expert_solves_the_first_seeds(env_id):
    result = success_rate(env_id, "expert", seeds=range(3))
    assert result["success_rate"] == 1.0, result


def test_random_actions_do_not_solve_peg_insertion_side():
    """The contrast that makes the test above mean something: success is not a given."""
    env = gym.make("PegInsertionSide-v1", obs_mode="state", control_mode="pd_ee_delta_pose")
    try:
        policy = get_policy("random", env, seed=0)
        obs, _ = env.reset(seed=0)
        solved = False
        for _ in range(60):
            obs, _, _, _, info = env.step(policy(obs))
            solved |= bool(info["success"].any())
        assert not solved
    finally:
        env.close()


def test_get_policy_gives_the_stock_expert_and_checks_the_control_mode():
    env = gym.make("PlugCharger-v1", obs_mode="state", control_mode="pd_ee_delta_pose")
    try:
        policy = get_policy("expert", env)
        assert isinstance(policy, PlugChargerExpert)
        obs, _ = env.reset(seed=0)
        action = policy(obs)
        assert action.shape == (1, 7) and action.abs().max() <= 1
    finally:
        env.close()
    env = gym.make("PegInsertionSide-v1", obs_mode="state", control_mode="pd_joint_delta_pos")
    try:
        with pytest.raises(ValueError, match="control_mode='pd_ee_delta_pose'.*pd_joint_delta_pos"):
            get_policy("expert", env)
    finally:
        env.close()


def test_stock_expert_restarts_at_each_reset():
    """One policy object over two episodes of the same seed gives the same actions: its phase resets."""
    env = gym.make("PegInsertionSide-v1", obs_mode="state", control_mode="pd_ee_delta_pose")
    try:
        policy = get_policy("expert", env)
        assert isinstance(policy, PegInsertionSideExpert)
        runs = []
        for _ in range(2):
            obs, _ = env.reset(seed=3)
            actions = []
            for _ in range(25):  # past the grasp: the phase has moved on by then
                actions.append(policy(obs))
                obs, *_ = env.step(actions[-1])
            runs.append(torch.cat(actions))
        assert int(policy.phase.max()) >= 3
        torch.testing.assert_close(runs[0], runs[1], atol=1e-5, rtol=0)
    finally:
        env.close()


def test_record_expert_on_a_stock_task_with_video(tmp_path):
    """record-expert on PlugCharger-v1: a successful observation + state demo and a video.

    ``RecordEpisode(info_on_video=True)`` crashes with numpy 2.4 in ManiSkill 3.0.1; the recorder
    keeps it off, so a video of a stock task is written all the same.
    """
    from drem_maniskill.experts.recording import record_expert

    rec = record_expert("PlugCharger-v1", str(tmp_path), seeds=[0], save_video=True)
    assert rec.success == [True] and rec.lengths[0] < 100
    meta = json.loads((tmp_path / "expert.json").read_text())
    assert meta["env_info"]["env_id"] == "PlugCharger-v1"
    assert meta["env_info"]["env_kwargs"]["control_mode"] == "pd_ee_delta_pose"
    with h5py.File(rec.h5_path, "r") as f:
        traj = f["traj_0"]
        steps = traj["actions"].shape[0]
        assert steps == rec.lengths[0] and traj["actions"].shape[1] == 7
        for cam in ("base_camera", "hand_camera"):
            rgb = traj["obs"]["sensor_data"][cam]["rgb"]
            assert rgb.shape == (steps + 1, 128, 128, 3) and rgb.dtype == np.uint8
        assert "env_states" in traj and traj["success"][-1]
    assert sorted(p.name for p in tmp_path.glob("*.mp4")) == ["0.mp4"]


@pytest.mark.parametrize("env_id", ["PegInsertionSide-v1", "PlugCharger-v1"])
def test_shipped_stock_checkpoint_rises_along_an_expert_episode(env_id):
    """rewards/<task>/drem.pt (image-only, the task's two cameras) on held-out seed 0."""
    from scipy.stats import spearmanr

    from drem_maniskill.drem.reward import default_checkpoint
    from drem_maniskill.drem.wrapper import DREMRewardWrapper

    path = default_checkpoint(env_id)
    env = DREMRewardWrapper(gym.make(env_id, obs_mode="state", control_mode="pd_ee_delta_pose"), str(path))
    try:
        assert env.reward_model.header["env_id"] == env_id
        assert env.reward_model.header["modalities"] == ["fixed", "wrist"]
        policy = get_policy("expert", env)
        obs, _ = env.reset(seed=0)
        rewards, success = [], False
        for _ in range(150):
            obs, reward, _, _, info = env.step(policy(obs))
            rewards.append(float(reward[0]))
            success = bool(info["success"][0])
            if success:
                break
        assert success
        assert rewards[0] < 0.5 < rewards[-1]
        assert spearmanr(np.arange(len(rewards)), rewards).correlation > 0.8
    finally:
        env.close()


def test_scripted_success_command_on_a_stock_task():
    """`drem-maniskill scripted-success` picks the end-effector controller the stock expert needs."""
    import subprocess
    import sys

    proc = subprocess.run([sys.executable, "-m", "drem_maniskill.cli", "scripted-success", "--task", "PegInsertionSide-v1",
                           "--episodes", "2"], capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr[-2000:]
    result = json.loads(proc.stdout[proc.stdout.index("{"):])
    assert result["env_id"] == "PegInsertionSide-v1" and result["episodes"] == 2 and result["success_rate"] == 1.0
