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
        obs = {"state": torch.full((1, 1), float(self.t))}
        return obs, torch.ones(1), success, torch.tensor([False]), {"success": success}


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


class Hooked(ManiSkillDictVecEnv):
    """``SubprocDictVecEnv``'s order of events in one process.

    Send the action, run ``while_stepping``, collect the step.
    """

    def __init__(self, model_updates, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self.while_stepping, self.model_updates, self.at_send, self.in_hook = None, model_updates, [], []

    def step_async(self, actions):
        self.at_send.append(self.model_updates())
        super().step_async(actions)

    def step_wait(self):
        if self.while_stepping is not None:
            before = self.model_updates()
            self.while_stepping()
            self.in_hook.append(self.model_updates() - before)
        return super().step_wait()


def _sac_updates_seen_by_each_action(overlap: bool, steps: int = 24, learning_starts: int = 4):
    from drem_maniskill.rl.sac import SAC

    holder = {}
    venv = Hooked(lambda: holder["model"]._n_updates, SucceedsAtStep3(), horizon=5)
    model = holder["model"] = SAC("MultiInputPolicy", venv, learning_starts=learning_starts, batch_size=4, seed=0,
                                  policy_kwargs=dict(net_arch=[8]))
    if overlap:
        model.train_while_env_steps(venv)
    model.learn(total_timesteps=steps)
    return model, venv


def test_overlapped_sac_makes_the_same_updates_while_the_env_steps_each_action_one_update_older(tmp_path):
    """``SAC.train_while_env_steps``: SB3's updates, each made while the next env step runs.

    The last one is made before ``learn`` returns.
    """
    plain, plain_env = _sac_updates_seen_by_each_action(overlap=False)
    model, venv = _sac_updates_seen_by_each_action(overlap=True)
    assert model._n_updates == plain._n_updates == 24 - 4
    # Every update but the last (made as learn returns) ran inside a step, between sending the action and its result.
    assert sum(venv.in_hook) == model._n_updates - 1 and set(venv.in_hook) <= {0, 1}
    # SB3 chooses action t after t - learning_starts updates; overlapped, after one fewer.
    assert plain_env.at_send[5:] == [t - 4 for t in range(5, 24)]
    assert venv.at_send == [max(n - 1, 0) for n in plain_env.at_send]
    # The deferral is not saved: a loaded model trains in SB3's order until it is hooked to an env again.
    model.save(tmp_path / "m.zip")
    assert model._deferred == [] and type(model).load(tmp_path / "m.zip", env=venv)._deferred is None


@pytest.mark.slow
def test_the_env_in_a_child_process_steps_like_the_env_in_this_one():
    """``SubprocDictVecEnv`` (``RLConfig.overlap_env``): the same observations, rewards and episode ends for the
    same seed and actions; an error in the child is raised here with its own type; a dead child is named."""
    from drem_maniskill.rl import RLConfig
    from drem_maniskill.rl.run_env import make_local_vec_env
    from drem_maniskill.rl.vec_env import SubprocDictVecEnv

    config = RLConfig.from_preset("state", task="PegInHole-v1", reward="engineered", overlap_env=True)
    here, _ = make_local_vec_env(config)
    child = SubprocDictVecEnv(make_local_vec_env, config)
    try:
        assert child.observation_space == here.observation_space and child.action_space == here.action_space
        for v in (here, child):
            v.seed(7)
        first = [here.reset(), child.reset()]
        assert all(np.array_equal(first[0][k], first[1][k]) for k in first[0])
        actions = np.random.default_rng(0).uniform(-1, 1, (60, 1, here.action_space.shape[0])).astype(np.float32)
        ends = 0
        for a in actions:
            (o1, r1, d1, i1), (o2, r2, d2, i2) = here.step(a), child.step(a)
            assert all(np.allclose(o1[k], o2[k], atol=1e-5) for k in o1)
            assert np.allclose(r1, r2, atol=1e-5) and np.array_equal(d1, d2)
            ends += int(d1[0])
            if d1[0]:
                assert i1[0]["episode"]["l"] == i2[0]["episode"]["l"]
        assert ends >= 1  # the 50-step time limit was crossed, and the child reset the same way
        assert child.env_time > 0
        child._proc.kill()
        child._proc.join()
        with pytest.raises(RuntimeError, match="child process ended without an answer"):
            child.step(actions[0])
    finally:
        here.close()
        child.close()
    missing = RLConfig.from_preset("state", task="PegInHole-v1", reward="drem",
                                   reward_checkpoint="/nonexistent/drem.pt", overlap_env=True)
    with pytest.raises(FileNotFoundError, match="/nonexistent/drem.pt"):
        SubprocDictVecEnv(make_local_vec_env, missing)
