"""The RL reward table: names, missing checkpoints, ManiSkill's own tasks."""

from __future__ import annotations

import pytest

from drem_maniskill.rl import REWARDS, RLConfig, reward_spec


def test_unknown_reward_is_a_clear_error(capsys):
    with pytest.raises(ValueError) as err:
        reward_spec("shaped")
    for name in REWARDS:
        assert name in str(err.value)
    assert "'shaped'" in str(err.value)
    from drem_maniskill.cli import main

    assert main(["train-policy", "--reward", "shaped", "--steps", "8"]) == 2
    assert "unknown reward 'shaped'; choose one of: sparse, dense" in capsys.readouterr().err


def test_missing_image_only_checkpoint_names_the_file(tmp_path, monkeypatch):
    import drem_maniskill.drem.checkpoint as checkpoints

    monkeypatch.setattr(checkpoints, "REWARDS_DIRS", (tmp_path,))
    with pytest.raises(FileNotFoundError, match=r"drem_image\.pt.*train-reward .*--model-modalities fixed wrist"):
        REWARDS["drem-image"].make("PegInHole-v1", {})


def test_sac_env_on_a_stock_task(tmp_path, monkeypatch):
    """PlugCharger-v1 (ManiSkill's, no F/T, sparse only): its two cameras and state; drem through the wrapper."""
    from pathlib import Path

    import torch

    import drem_maniskill.drem.checkpoint as checkpoints
    from drem_maniskill.rl.run_env import make_env
    from tests.conftest import tiny_stock_checkpoint

    ckpt = Path(tiny_stock_checkpoint(tmp_path / "drem.pt", env_id="PlugCharger-v1"))
    monkeypatch.setattr(checkpoints, "default_checkpoint",
                        lambda task, image_only=False: ckpt if task == "PlugCharger-v1" else tmp_path / "none.pt")
    sparse = RLConfig.from_preset("light", task="PlugCharger-v1", reward="sparse")
    assert not sparse.uses_ft
    env, vice = make_env(sparse, for_eval=True)
    try:
        assert vice is None
        obs, _ = env.reset(seed=0)
        assert set(obs) == {"base_camera", "hand_camera", "state"}
        assert obs["base_camera"].shape == (1, 3, 32, 32) and obs["base_camera"].dtype == torch.uint8
        assert obs["state"].shape == (1, 9 + 7)  # qpos + tcp pose
        _, r, *_ = env.step(torch.zeros(1, 7))
        assert float(r[0]) == 0.0
    finally:
        env.close()
    env, _ = make_env(RLConfig.from_preset("light", task="PlugCharger-v1", reward="drem"), for_eval=True)
    try:
        env.reset(seed=0)
        _, r, _, _, info = env.step(torch.zeros(1, 7))
        assert float(info["original_reward"][0]) == 0.0 and float(r[0]) != 0.0
    finally:
        env.close()
    with pytest.raises(ValueError, match=r"PlugCharger-v1 the rewards are \['sparse', 'drem'\].*'engineered'"):
        make_env(RLConfig.from_preset("light", task="PlugCharger-v1", reward="engineered"))


def test_dense_is_maniskills_own_on_the_stock_tasks_that_define_one():
    """PlugCharger-v1 has no dense reward of its own; StackCube-v1 has, and ``dense`` pays it normalised."""
    import torch

    from drem_maniskill.rl.rewards import supported_rewards
    from drem_maniskill.rl.run_env import make_env

    assert "dense" in supported_rewards("StackCube-v1") and "dense" not in supported_rewards("PlugCharger-v1")
    env, _ = make_env(RLConfig.from_preset("state", task="StackCube-v1", reward="dense"), for_eval=True)
    try:
        obs, _ = env.reset(seed=0)
        _, r, _, _, info = env.step(torch.zeros(1, 7))
        u = env.unwrapped
        assert u.reward_mode == "normalized_dense"
        expected = u.compute_normalized_dense_reward(obs=None, action=torch.zeros(1, 7), info=info)
        assert 0.0 < float(r[0]) < 1.0 and float(r[0]) == pytest.approx(float(expected[0]))
    finally:
        env.close()


def test_a_run_can_name_its_own_reward_checkpoint(tmp_path):
    """``reward_checkpoint`` (``--reward-checkpoint``) replaces the shipped one, for the DREM rewards only."""
    import torch

    from drem_maniskill.drem.checkpoint import default_checkpoint
    from drem_maniskill.rl.run_env import make_env
    from tests.conftest import tiny_checkpoint

    ckpt = tiny_checkpoint(tmp_path / "drem.pt", "PegInHole-v1")
    env, _ = make_env(RLConfig.from_preset("state", reward="drem", reward_checkpoint=ckpt), for_eval=True)
    try:
        loaded = env.unwrapped.drem_reward
        assert torch.equal(loaded.h_goal, torch.load(ckpt, weights_only=False)["weights"]["h_goal"])
        assert default_checkpoint("PegInHole-v1") != ckpt
    finally:
        env.close()
    with pytest.raises(FileNotFoundError, match=r"nowhere\.pt not found.*--reward-checkpoint PATH"):
        make_env(RLConfig.from_preset("state", reward="drem", reward_checkpoint=str(tmp_path / "nowhere.pt")),
                 for_eval=True)
    with pytest.raises(ValueError, match="for the DREM rewards, not 'engineered'"):
        make_env(RLConfig.from_preset("state", reward="engineered", reward_checkpoint=ckpt), for_eval=True)


def test_the_shifted_drem_form_pays_r_minus_one_and_is_refused_where_it_would_mislead(tmp_path):
    """``drem_form="shifted"`` (``--drem-form``) pays R - 1 for the same state.

    The guard and the non-DREM rewards refuse it.
    """
    import torch

    from drem_maniskill.rl.run_env import make_env
    from tests.conftest import tiny_checkpoint

    ckpt = tiny_checkpoint(tmp_path / "drem.pt", "PegInHole-v1")
    rewards = {}
    for form in ("paper", "shifted"):
        config = RLConfig.from_preset("state", reward="drem", reward_checkpoint=ckpt, drem_form=form)
        env, _ = make_env(config, for_eval=True)
        try:
            env.reset(seed=5)
            action = torch.zeros(1, 6)
            action[0, 2] = -0.5
            rewards[form] = torch.stack([env.step(action)[1] for _ in range(3)])
        finally:
            env.close()
    torch.testing.assert_close(rewards["shifted"], rewards["paper"] - 1.0)
    assert (rewards["shifted"] <= 0).all()
    # Unset, the form follows termination: episodes that end at success get the shifted one.
    assert RLConfig.from_preset("state", reward="drem").drem_form_used == "shifted"
    assert RLConfig.from_preset("state", reward="drem", terminate_on_success=False).drem_form_used == "paper"
    assert RLConfig.from_preset("paper", reward="drem").drem_form_used == "paper"
    with pytest.raises(ValueError, match="unknown drem_form 'negative'.*'paper', 'shifted'"):
        RLConfig.from_preset("state", drem_form="negative")
    with pytest.raises(ValueError, match="for the DREM rewards, not 'engineered'"):
        make_env(RLConfig.from_preset("state", reward="engineered", drem_form="shifted"), for_eval=True)
    with pytest.raises(ValueError, match="drem-guarded pays only the paper's form"):
        config = RLConfig.from_preset("state", reward="drem-guarded", reward_checkpoint=ckpt, drem_form="shifted")
        make_env(config, for_eval=True)
