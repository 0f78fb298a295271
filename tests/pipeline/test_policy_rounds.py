"""Policy rounds: hard negatives from a policy trained on the reward, recorded in the header, resumable."""

from __future__ import annotations

import dataclasses
import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import h5py
import numpy as np
import pytest
import torch

from drem_maniskill.drem.checkpoint import load_checkpoint
from drem_maniskill.pipeline.policy_rounds import (RoundsConfig, paid_at_depth, paid_by_depth, run_rounds,
                                                   stall_depth, stalled_steps, trap_threshold, tree_pay)
from drem_maniskill.pipeline.recipe import RecipeError, load_recipe

# One round: 300 SAC steps (gradient steps after 200), two policy episodes, 60 fine-tuning iterations.
# Labelled deep (30 of the tiny tree's ~60 depths) so that a barely trained reward still over-pays some states.
ROUNDS = RoundsConfig(rounds=1, sac_steps=300, learning_starts=200, episodes=2, iterations=60, negative_depth=30)
# The same round looking for stalls too: the last quarter of a failed episode, where its reward stopped rising.
STALLS = dataclasses.replace(ROUNDS, stall_window=0.25)

SCRIPT = """
import json, sys
from drem_maniskill.pipeline.policy_rounds import RoundsConfig, run_rounds
from drem_maniskill.pipeline.train_reward import TrainConfig
a = json.loads(sys.argv[1])
config = TrainConfig(**{**a["train"], "model": __import__("drem_maniskill.drem.model", fromlist=["ModelConfig"])
                        .ModelConfig(**a["train"]["model"])})
print(run_rounds("PegInHole-v1", a["tree"], a["checkpoint"], config, RoundsConfig(**a["rounds"]), a["out"]))
"""


@pytest.fixture(scope="module")
def tiny(tmp_path_factory):
    """The tiny recipe's tree and reward of PegInHole-v1, and its training config (saving every 10 iterations)."""
    from drem_maniskill.pipeline import backward_sample
    from drem_maniskill.pipeline.dataset import dataset_modalities
    from drem_maniskill.pipeline.train_reward import train_reward

    r = load_recipe("PegInHole-v1", "tiny")
    work = tmp_path_factory.mktemp("rounds")
    tree = backward_sample(str(r.expert_file()), str(work / "tree.h5"), r.sampler_config())
    config = dataclasses.replace(r.train_config(modalities=dataset_modalities(tree)), save_every=10)
    checkpoint = train_reward(tree, str(work / "reward"), config, progress=False)
    return tree, config, checkpoint


@pytest.fixture(scope="module")
def stalls_round(tiny, tmp_path_factory):
    """``(its folder, its last checkpoint)``: one round of ``STALLS`` on the tiny reward, run once for the module."""
    tree, config, checkpoint = tiny
    out = tmp_path_factory.mktemp("stalls_round")
    return out, run_rounds("PegInHole-v1", tree, checkpoint, config, STALLS, out)


def _rewards(checkpoint, negatives: Path) -> torch.Tensor:
    from drem_maniskill.drem.reward import DREMReward

    reward = DREMReward.from_checkpoint(str(checkpoint))
    with h5py.File(negatives, "r") as f:
        batch = {m: torch.as_tensor(f[f"{m}_rgb"][()]) for m in reward.model.config.cameras}
        batch["ft"] = torch.as_tensor(f["ft"][()]).float()
    return reward(batch)


@pytest.mark.slow
def test_a_round_adds_the_over_paid_and_stalled_states_of_failed_episodes_and_pays_them_less(tiny, stalls_round):
    tree, config, checkpoint = tiny
    out, last = stalls_round
    header, _ = load_checkpoint(str(last))
    (record,) = header["rounds"]
    assert record["round"] == 1 and record["negative_depth"] == 30 and record["sac_steps"] == 300
    assert record["episodes"] == 2 and record["failed"] == 2  # 300 steps teach no insertion
    negatives = out / "round_1" / "negatives.h5"
    with h5py.File(negatives, "r") as f:
        depth, paid, step = f["depth"][()], f["reward"][()], f["step"][()]
        assert len(depth) == record["negatives"] > 0
        assert f["fixed_rgb"].shape[1:] == (128, 128, 3) and f["ft"].shape[1:] == (8, 6)
    # Traps: paid at least what the reward pays the tree's nodes at depth 30, labelled 30.
    trap = paid >= record["threshold"] - 1e-4
    assert trap.sum() == record["candidates"] > 0 and set(depth[trap]) == {30}
    # Stalls: paid less, from an episode's last quarter, labelled eps + 1 beyond the depth paid no more than them.
    stall = ~trap
    assert stall.sum() == record["stall_candidates"] > 0 and 1 <= record["stalled"] <= 2
    curve = paid_by_depth(*tree_pay(checkpoint, tree))
    assert list(depth[stall]) == [stall_depth(float(r), *curve, config.eps) for r in paid[stall]]
    assert all(depth[stall] > curve[0][curve[1] <= paid[stall].max()].min())
    horizon = max(step) + 1
    assert all(step[stall] >= horizon - round(0.25 * horizon))
    before = _rewards(checkpoint, negatives)
    assert before.numpy() == pytest.approx(paid, abs=1e-4)
    assert record["reward_before"] == pytest.approx(float(before.mean()), abs=1e-4)
    after = _rewards(last, negatives)
    assert record["reward_after"] == pytest.approx(float(after.mean()), abs=1e-4)
    assert float(after.mean()) < float(before.mean())  # labelled farther from the goal, they are paid less
    assert header["train"]["iterations"] == 60 and header["fit"]["tree_order"] > 0


def test_an_episode_stalled_where_its_reward_stopped_rising_and_is_labelled_beyond_what_it_is_paid_like():
    assert list(stalled_steps([0.1, 0.3, 0.5, 0.6, 0.6, 0.61, 0.6, 0.6], 0.25, 0.02)) == [6, 7]
    assert list(stalled_steps([0.1, 0.3, 0.5, 0.6, 0.6, 0.61, 0.7, 0.8], 0.25, 0.02)) == []  # still rising
    assert list(stalled_steps([0.5, 0.5], 0.5, 0.02)) == [1] and list(stalled_steps([0.5], 0.5, 0.02)) == []
    depths, paid = np.arange(10), 1 - np.arange(10) / 10  # depth d paid 1 - d / 10
    assert stall_depth(0.63, depths, paid, 4.0) == 4 + 5  # depth 4 is the nearest paid no more than 0.63
    assert stall_depth(0.6, depths, paid, 4.0) == 4 + 5
    assert stall_depth(1.5, depths, paid, 4.0) == 0 + 5  # paid above the goal: beyond the goal's neighbours
    assert stall_depth(-1.0, depths, paid, 4.0) == 9 + 5  # paid below every depth: beyond the deepest


@pytest.mark.slow
def test_a_round_killed_while_fine_tuning_and_rerun_ends_with_the_same_checkpoint(tiny, stalls_round, tmp_path):
    tree, config, checkpoint = tiny
    first, last = stalls_round
    # The same round again from its finished SAC run and negatives, killed at its first training checkpoint.
    second = tmp_path / "second"
    shutil.copytree(first, second, ignore=shutil.ignore_patterns("train"))
    args = json.dumps(dict(tree=tree, checkpoint=str(checkpoint), out=str(second), rounds=dataclasses.asdict(STALLS),
                           train={**dataclasses.asdict(config), "model": config.model.to_dict()}))
    state = second / "round_1" / "train" / "train_state.pt"
    proc = subprocess.Popen([sys.executable, "-c", SCRIPT, args], start_new_session=True,
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    deadline = time.time() + 300
    while proc.poll() is None and not state.exists() and time.time() < deadline:
        time.sleep(0.05)
    os.killpg(proc.pid, signal.SIGKILL)
    proc.wait()
    assert state.exists() and not (second / "round_1" / "train" / "drem.pt").exists()
    assert torch.load(state, weights_only=True)["step"] < STALLS.iterations
    done = subprocess.run([sys.executable, "-c", SCRIPT, args], capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr[-2000:]
    again = Path(done.stdout.strip().splitlines()[-1])
    (h1, w1), (h2, w2) = load_checkpoint(str(last)), load_checkpoint(str(again))
    assert h1 == h2
    assert all(torch.equal(w1[k], w2[k]) for k in w1)


def test_a_recipe_takes_rounds_and_refuses_an_unknown_key():
    raw = {"rounds": {"rounds": 2, "sac_steps": 5000}}
    assert load_recipe("Any-v1", recipe=raw).rounds_config() == RoundsConfig(rounds=2, sac_steps=5000)
    assert load_recipe("Any-v1", recipe={}).rounds_config().rounds == 0  # the paper's pipeline
    with pytest.raises(RecipeError, match="unknown key 'round'"):
        load_recipe("Any-v1", recipe={"rounds": {"round": 2}})


def test_traps_are_labelled_negative_depth_or_the_start_regions_depth_and_a_bad_label_is_named():
    assert RoundsConfig().trap_depth(4.0, 38) == 9  # 2 eps + 1
    assert RoundsConfig(negative_depth=12).trap_depth(4.0, 38) == 12
    start = RoundsConfig(negative_depth=12, trap_label="start")
    assert start.trap_depth(4.0, 38) == 38 and start.depth(4.0) == 12  # found by depth 12's pay, labelled 38
    with pytest.raises(ValueError, match="never reached the start region"):
        start.trap_depth(4.0, None)
    with pytest.raises(ValueError, match=r"rounds.trap_label = 'far'.*\['depth', 'start'\]"):
        RoundsConfig(trap_label="far")
    with pytest.raises(RecipeError, match="trap_label"):
        load_recipe("PegInHole-v1", "full", {"rounds": {"trap_label": "far"}})


def test_a_trap_is_paid_at_least_negative_depths_pay_or_a_share_of_the_goals(tiny):
    tree, config, checkpoint = tiny
    reward, data = tree_pay(checkpoint, tree)
    goal, deep = paid_at_depth(reward, data, 0), paid_at_depth(reward, data, 30)
    assert goal > deep  # the reward rises toward the goal, so the two rules differ
    assert trap_threshold(reward, data, ROUNDS, 30) == pytest.approx(deep)
    share = dataclasses.replace(ROUNDS, trap_share=0.8)
    assert trap_threshold(reward, data, share, 30) == pytest.approx(0.8 * goal)
    for bad in (0.0, 1.5):
        with pytest.raises(ValueError, match=r"rounds.trap_share must be in \(0, 1\]"):
            RoundsConfig(trap_share=bad)
