"""drem-rounds: the reward fine-tuned during a run on its failed episodes' over-paid states, the buffer paid again."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import gymnasium as gym
import h5py
import numpy as np
import pytest
import torch

from drem_maniskill.drem.checkpoint import load_checkpoint
from drem_maniskill.experts import ee_control_kwargs, get_policy
from drem_maniskill.pipeline.online_rounds import OnlineRounds, OnlineRoundsConfig
from drem_maniskill.pipeline.recipe import load_recipe
from drem_maniskill.pipeline.tree.tree_file import start_depth


@pytest.fixture(scope="module")
def tiny(tmp_path_factory):
    """The tiny recipe's tree and reward of PegInHole-v1 (its tree reaches the start region)."""
    from drem_maniskill.pipeline import backward_sample
    from drem_maniskill.pipeline.dataset import dataset_modalities
    from drem_maniskill.pipeline.train_reward import train_reward

    r = load_recipe("PegInHole-v1", "tiny")
    work = tmp_path_factory.mktemp("online")
    tree = backward_sample(str(r.expert_file()), str(work / "tree.h5"), r.sampler_config())
    checkpoint = train_reward(tree, str(work / "reward"), r.train_config(modalities=dataset_modalities(tree)),
                              progress=False)
    return str(tree), str(checkpoint)


def _env(checkpoint):
    return gym.make("PegInHole-v1", obs_mode="state_dict", reward_mode="drem", drem_checkpoint=checkpoint,
                    drem_form="shifted", **ee_control_kwargs("PegInHole-v1"))


class _Buffer:
    """What ``relabel`` reads of SB3's replay buffer."""

    def __init__(self, size: int, steps: int, n: int = 1):
        self.buffer_size, self.pos = size, steps % size
        self.rewards = np.full((size, n), 7.0, np.float32)


def _episode(learner, steps: int, seed: int, success: bool = False, held: int = 0) -> None:
    """The expert's first ``steps`` (toward the goal, so a barely trained reward pays some of them), then ``held``
    steps of a zero action: the episode comes to rest."""
    obs, _ = learner.reset(seed=seed)
    expert = get_policy("expert", learner.unwrapped)
    for _ in range(steps):
        obs, *_ = learner.step(expert(obs))
    still = torch.zeros(learner.action_space.shape)
    for _ in range(held):
        learner.step(still)
    learner.success[:] = success


def test_an_update_labels_failed_episodes_paid_states_at_the_start_depth_and_pays_them_less(tiny, tmp_path):
    tree, checkpoint = tiny
    env = _env(checkpoint)
    try:
        config = OnlineRoundsConfig(tree=tree, iterations=60, trap_share=0.3, keep=64, min_share=0.1)
        learner = OnlineRounds(env, config, tmp_path / "rounds")
        _episode(learner, 30, seed=2, success=True)
        _episode(learner, 30, seed=2)  # the same states as the first, which succeeded: none of those is a trap
        assert not learner.pending and (learner.paid[:30, 0] >= 0.3).any()
        learner.reset(seed=3)  # ends the second episode, failed
        failed = learner.paid[30:60, 0]
        assert [t for t, _, _ in learner.pending] == [t for t in range(30, 60) if failed[t - 30] >= 0.3]
        pending = list(learner.pending)
        traps = len(learner.pending)
        assert traps > 0
        eval_env = learner.evaluation_env(_env(checkpoint))
        out = learner.update()
        assert out["traps"] == traps and not learner.pending
        assert out["paid_after"] < out["paid_before"]
        header, _ = load_checkpoint(learner.checkpoint)
        assert header["online_rounds"]["trap_label"] == start_depth(Path(tree))
        # A few traps among the tree's nodes are repeated to min_share of them, so the fine-tuning samples them.
        nodes = len(h5py.File(tree, "r")["depth"])
        assert header["online_rounds"]["repeat"] == int(np.ceil(0.1 * nodes / traps)) > 1
        assert len(learner._data.depth) == nodes + traps * header["online_rounds"]["repeat"]
        with h5py.File(learner.negatives[-1], "r") as f:
            assert (f["depth"][()] == start_depth(Path(tree))).all() and sorted(f["step"][()]) == [
                t for t, _, _ in sorted(pending)]
        # The training and evaluation envs are paid by the fine-tuned reward from now on.
        for e in (env, eval_env):
            assert e.unwrapped.drem_checkpoint == learner.checkpoint
        # The buffer's rows since the run began are paid again, each as the new reward pays its state (shifted).
        buffer = _Buffer(size=100, steps=learner.steps)
        assert learner.steps == 60
        assert learner.relabel(buffer) == learner.steps
        again = learner._pay({**{c: learner.images[c][:learner.steps, 0] for c in learner.cameras},
                              "ft": learner.ft[:learner.steps, 0]})
        np.testing.assert_allclose(buffer.rewards[:learner.steps, 0], again.numpy() - 1.0, atol=1e-5)
        assert (buffer.rewards[learner.steps:] == 7.0).all()
        assert learner.relabel(buffer) == 0  # nothing changed since
        eval_env.close()
    finally:
        env.close()

        # A resumed run goes on from the last update: its reward, and the step count the buffer is aligned with.
        state = learner.state_dict()
        again = OnlineRounds(_env(checkpoint), config, tmp_path / "rounds", state=state)
        assert again.unwrapped.drem_checkpoint == learner.checkpoint and again.steps == 60 and again.updates == 1
        assert again.repeats == learner.repeats
        again.close()


@pytest.mark.parametrize("label", ["start", "depth"])
def test_a_failed_episode_that_comes_to_rest_gives_its_last_steps_as_stalls(tiny, tmp_path, label):
    from drem_maniskill.pipeline.policy_rounds import paid_by_depth
    from drem_maniskill.pipeline.train_reward import train_config_of

    tree, checkpoint = tiny
    env = _env(checkpoint)
    try:
        config = OnlineRoundsConfig(tree=tree, iterations=20, trap_share=1.0, keep=64, stall_window=0.25,
                                    stall_rise=0.05, stall_label=label)
        learner = OnlineRounds(env, config, tmp_path / "rounds")
        _episode(learner, 8, seed=2, held=32)
        learner.reset(seed=3)
        paid = learner.paid[:40, 0]
        # At rest the pay stays put, so the last quarter beats the best before it by less than stall_rise.
        assert float(paid[30:].max() - paid[:30].max()) < 0.05
        assert [(t, s) for t, _, s in learner.pending] == [(t, True) for t in range(30, 40)]
        # Without a stall window the same episode gives nothing: no step is paid like the goal.
        plain = OnlineRounds(_env(checkpoint), dataclasses.replace(config, stall_window=0.0), tmp_path / "plain")
        _episode(plain, 8, seed=2, held=32)
        plain.reset(seed=3)
        assert not plain.pending
        plain.close()
        train = train_config_of(load_checkpoint(checkpoint)[0])
        depths, curve = paid_by_depth(env.unwrapped.drem_reward, learner._tree_data(train))
        out = learner.update()
        assert out["stalled"] == 10 == out["traps"]
        with h5py.File(learner.negatives[-1], "r") as f:
            got, pay = f["depth"][()], f["reward"][()]
        if label == "start":
            assert (got == start_depth(Path(tree))).all()
        else:
            for d, r in zip(got, pay):  # eps + 1 beyond the nearest depth paid no more than the step
                nearest = depths[curve <= r].min() if (curve <= r).any() else depths.max()
                assert d == nearest + int(train.eps) + 1
    finally:
        env.close()


def test_a_bad_setting_or_a_missing_tree_is_named(tiny, tmp_path):
    tree, checkpoint = tiny
    with pytest.raises(ValueError, match="trap_share"):
        OnlineRoundsConfig(trap_share=0.0)
    with pytest.raises(ValueError, match="update_every"):
        OnlineRoundsConfig(update_every=0)
    with pytest.raises(ValueError, match="min_share"):
        OnlineRoundsConfig(min_share=1.5)
    with pytest.raises(ValueError, match="stall_window"):
        OnlineRoundsConfig(stall_window=1.0)
    with pytest.raises(ValueError, match="stall_label"):
        OnlineRoundsConfig(stall_label="goal")
    env = _env(checkpoint)
    try:
        with pytest.raises(FileNotFoundError, match="reward_kwargs tree="):
            OnlineRounds(env, OnlineRoundsConfig(tree=str(tmp_path / "none.h5")), tmp_path)
    finally:
        env.close()
    sparse = gym.make("PegInHole-v1", obs_mode="state_dict", reward_mode="sparse")
    try:
        with pytest.raises(ValueError, match="reward_mode='drem'"):
            OnlineRounds(sparse, OnlineRoundsConfig(tree=tree), tmp_path)
    finally:
        sparse.close()


@pytest.mark.slow
def test_a_drem_rounds_run_updates_its_reward_resumes_and_is_checked_on_the_reward_it_ended_on(tiny, tmp_path):
    from drem_maniskill.evaluate.check_reward import CheckConfig, given_run
    from drem_maniskill.rl.config import RLConfig
    from drem_maniskill.rl.train_policy import train_policy

    tree, checkpoint = tiny
    options = dict(tree=tree, update_every=60, iterations=5, trap_share=0.01, keep=200)
    run = RLConfig.from_preset("state", task="PegInHole-v1", reward="drem-rounds", seed=0, steps=120,
                               learning_starts=40, eval_every=60, eval_episodes=1, reward_checkpoint=checkpoint,
                               reward_kwargs=options, out=str(tmp_path / "run"), train_bf16=False, overlap_env=False)
    train_policy(dataclasses.replace(run, steps=60))
    first = torch.load(tmp_path / "run" / "checkpoints" / "step_60" / "drem-rounds.pt", weights_only=True)
    assert first["steps"] == 60
    train_policy(run)  # resumed at 60
    state = torch.load(tmp_path / "run" / "checkpoints" / "step_120" / "drem-rounds.pt", weights_only=True)
    assert state["steps"] == 120 and state["updates"] >= 1
    assert Path(state["checkpoint"]).is_relative_to(tmp_path / "run" / "drem-rounds")
    policy, judged, _ = given_run(CheckConfig(task="PegInHole-v1", run=str(tmp_path / "run")))
    assert policy.config.reward == "drem" and str(judged) == state["checkpoint"]
