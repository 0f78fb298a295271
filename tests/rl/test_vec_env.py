"""The SB3 adapter's episode ends: at the time limit (truncated, bootstrapped), or at success when asked (terminal)."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from gymnasium import spaces

from drem_maniskill.rl.vec_env import ManiSkillDictVecEnv


class SucceedsAtStep3:
    """A one-env stand-in for a batched ManiSkill env whose task succeeds from its third step on."""

    num_envs = 1
    single_observation_space = spaces.Dict({"state": spaces.Box(-10, 10, (1,), np.float32)})
    single_action_space = spaces.Box(-1, 1, (1,), np.float32)

    @property
    def unwrapped(self):
        return self

    def reset(self, seed=None, options=None):
        self.t = 0
        return {"state": torch.zeros(1, 1)}, {}

    def step(self, action):
        self.t += 1
        success = torch.tensor([self.t >= 3])
        return {"state": torch.full((1, 1), float(self.t))}, torch.ones(1), success, torch.tensor([False]), {"success": success}


@pytest.mark.parametrize("terminate", [False, True])
def test_success_ends_an_episode_as_a_terminal_state_only_when_asked(terminate):
    venv = ManiSkillDictVecEnv(SucceedsAtStep3(), horizon=5, terminate_on_success=terminate)
    venv.reset()
    ends = []
    for _ in range(10):
        venv.step_async(np.zeros((1, 1), np.float32))
        obs, rew, done, infos = venv.step_wait()
        if done[0]:
            ends.append(infos[0])
            # The next episode starts from the reset observation; the last one is kept aside.
            assert obs["state"][0, 0] == 0 and infos[0]["terminal_observation"]["state"][0] > 0
    if terminate:
        assert [e["episode"]["l"] for e in ends] == [3, 3, 3]
        assert all(e["is_success"] and e["TimeLimit.truncated"] is False for e in ends)
    else:
        assert [e["episode"]["l"] for e in ends] == [5, 5]
        assert all(e["is_success"] and e["TimeLimit.truncated"] is True for e in ends)
