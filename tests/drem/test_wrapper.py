"""DREMRewardWrapper: the reward replaced, the original kept in info."""

from __future__ import annotations

import gymnasium as gym
import pytest
import torch


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


def test_a_wrapped_reward_read_once_at_an_episodes_end_is_what_its_last_step_pays():
    """The wrapper's steps skip the reward inside ``reward_read_at_end`` (they pay 0) and the one read after them
    pays what the last step pays with the reward on; each in a new env, as an episode after another in the same env
    does not replay it (the controller keeps its state). A guard on the reward leaves nothing to read once."""
    from drem_maniskill.drem.checkpoint import default_checkpoint
    from drem_maniskill.drem.guard import SupportGuard, load_support
    from drem_maniskill.drem.wrapper import DREMRewardWrapper, drem_source, reward_read_at_end
    from drem_maniskill.evaluate.probes import hold_targets
    from drem_maniskill.experts import rollout
    from drem_maniskill.experts.scripted import HoldPolicy

    checkpoint = default_checkpoint("PegInHole-v1")

    def hold(read_at_end: bool):
        env = DREMRewardWrapper(gym.make("PegInHole-v1", obs_mode="state_dict", reward_mode="sparse"), checkpoint)
        try:
            policy = HoldPolicy(env, hold_targets(env)["pressed 3 mm beside"])  # in contact: F/T not zero
            if not read_at_end:
                return rollout(env, policy, 3, 8, stop_on_success=False), None
            assert drem_source(env) is env
            with reward_read_at_end(env) as read:
                ep = rollout(env, policy, 3, 8, stop_on_success=False)
                value = float(read()[0])
            assert not env.paused
            return ep, value
        finally:
            env.close()

    paid, _ = hold(False)
    unpaid, value = hold(True)
    assert set(unpaid.rewards) == {0.0} and len(set(paid.rewards)) > 1
    assert value == pytest.approx(paid.rewards[-1], abs=1e-6)

    env = gym.make("PegInHole-v1", obs_mode="state_dict", reward_mode="drem")
    try:
        assert drem_source(env) is env.unwrapped
        guarded = SupportGuard(env, load_support(checkpoint.parent / "support.json"))
        assert drem_source(guarded) is None
        with pytest.raises(ValueError, match="DREM reward"):
            with reward_read_at_end(guarded):
                pass
    finally:
        env.close()
