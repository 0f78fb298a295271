"""The ``drem`` reward mode mixin: ManiSkill's error types for unknown modes, one route into ``env.step``."""

from __future__ import annotations

import gymnasium as gym
import pytest
import torch

from drem_maniskill.drem.mode import DREMRewardMode, UnsupportedModeError
from drem_maniskill.drem.wrapper import DREMRewardWrapper
from drem_maniskill.envs import InsertionEnv


@pytest.mark.parametrize("env_id", ["PegInHole-v1", "USBInsertion-DREM-v1"])
def test_unknown_reward_mode_is_maniskills_not_implemented_error_and_a_value_error(env_id):
    with pytest.raises(NotImplementedError, match=r"Unknown reward_mode 'dreamy'.*normalized_dense.*'drem'"):
        gym.make(env_id, reward_mode="dreamy")
    with pytest.raises(ValueError, match=r"Unknown reward_mode 'dreamy'"):
        gym.make(env_id, reward_mode="dreamy")
    assert issubclass(UnsupportedModeError, NotImplementedError) and issubclass(UnsupportedModeError, ValueError)


def _error_of(env_id: str, **kwargs) -> tuple:
    with pytest.raises(Exception) as err:
        gym.make(env_id, **kwargs)
    return type(err.value), str(err.value)


@pytest.mark.parametrize("kwargs", [dict(obs_mode="smell"), dict(control_mode="telepathy")])
def test_unknown_obs_and_control_modes_fail_as_on_maniskills_own_tasks(kwargs):
    """Ours leave these checks to ManiSkill: the same exception type and message as PegInsertionSide-v1."""
    ours, stock = _error_of("PegInHole-v1", **kwargs), _error_of("PegInsertionSide-v1", **kwargs)
    assert ours[0] is stock[0] and issubclass(ours[0], AssertionError)
    assert list(kwargs.values())[0] in ours[1]


def test_our_tasks_take_the_drem_mode_from_the_mixin():
    assert issubclass(InsertionEnv, DREMRewardMode)
    assert "drem" in InsertionEnv.SUPPORTED_REWARD_MODES
    assert InsertionEnv.REWARD_FUNCTIONS["drem"] == "compute_drem_reward"
    assert InsertionEnv.compute_drem_reward is DREMRewardMode.compute_drem_reward


def test_mode_and_wrapper_give_the_same_reward():
    """reward_mode="drem" and DREMRewardWrapper around reward_mode="none" build the same inputs: equal rewards."""
    from drem_maniskill.drem.checkpoint import default_checkpoint

    path = str(default_checkpoint("PegInHole-v1"))
    mode = gym.make("PegInHole-v1", obs_mode="state", reward_mode="drem")
    wrapped = DREMRewardWrapper(gym.make("PegInHole-v1", obs_mode="rgb", reward_mode="none"), path)
    try:
        assert mode.unwrapped.drem_reward is not None and wrapped.unwrapped.drem_reward is None
        mode.reset(seed=5)
        wrapped.reset(seed=5)
        for k in range(3):
            action = torch.full((1, 6), 0.3 * (-1) ** k)
            _, r_mode, *_ = mode.step(action)
            _, r_wrap, _, _, info = wrapped.step(action)
            assert float(info["original_reward"][0]) == 0.0
            assert abs(float(r_mode[0]) - float(r_wrap[0])) < 1e-5
    finally:
        mode.close()
        wrapped.close()
