"""The shared-encoder SAC step (rl.sac): one extractor, trained by the critic loss only, run twice per step."""

import gymnasium as gym
import numpy as np
import pytest
import torch

from drem_maniskill.rl.algos import build_sac
from drem_maniskill.rl.config import RLConfig
from drem_maniskill.rl.sac import SAC, SharedEncoderPolicy


class TinyCameraEnv(gym.Env):
    """A 16 px camera, a state vector and a reward for moving toward +1: enough for SAC to take gradient steps."""

    observation_space = gym.spaces.Dict({
        "fixed_camera": gym.spaces.Box(0, 255, (3, 16, 16), np.uint8),
        "state": gym.spaces.Box(-np.inf, np.inf, (4,), np.float32),
    })
    action_space = gym.spaces.Box(-1, 1, (2,), np.float32)

    def _obs(self):
        img = self.np_random.integers(0, 256, (3, 16, 16), dtype=np.uint8)
        return {"fixed_camera": img, "state": self.np_random.normal(size=4).astype(np.float32)}

    def reset(self, *, seed=None, options=None):
        """A random observation."""
        super().reset(seed=seed)
        self.t = 0
        return self._obs(), {}

    def step(self, action):
        """Reward 10x the first action coordinate; 10-step episodes."""
        self.t += 1
        return self._obs(), 10.0 * float(action[0]), False, self.t >= 10, {}


def _model(tmp_path, shared: bool, **overrides):
    # One gradient step per env step, so that 300 steps are enough to learn the bandit.
    overrides = dict(train_freq=1, **overrides)
    config = RLConfig.from_preset("light", cameras=("fixed_camera",), image_size=16, policy_ft=False,
                                  shared_encoder=shared, batch_size=16, learning_starts=32, buffer_size=200,
                                  steps=200, out=str(tmp_path), device="cpu", **overrides)
    model = build_sac(config, _vec())
    model.learn(total_timesteps=40)  # fills the buffer past learning_starts, a few gradient steps
    return model


def _vec():
    from stable_baselines3.common.vec_env import DummyVecEnv

    return DummyVecEnv([TinyCameraEnv])


def _extractor_params(model):
    return {n: p.detach().clone() for n, p in model.actor.features_extractor.named_parameters()}


def test_actor_and_critic_share_one_extractor_that_only_the_critic_optimiser_trains(tmp_path):
    model = _model(tmp_path, shared=True)
    policy = model.policy
    assert isinstance(policy, SharedEncoderPolicy) and isinstance(model, SAC)
    assert policy.critic.features_extractor is policy.actor.features_extractor
    assert policy.critic_target.features_extractor is not policy.actor.features_extractor
    encoder = {id(p) for p in policy.actor.features_extractor.parameters()}
    in_actor_opt = {id(p) for g in policy.actor.optimizer.param_groups for p in g["params"]}
    in_critic_opt = {id(p) for g in policy.critic.optimizer.param_groups for p in g["params"]}
    assert not encoder & in_actor_opt
    assert encoder <= in_critic_opt
    assert {id(p) for p in policy.actor.mu.parameters()} <= in_actor_opt


def test_the_actor_loss_does_not_move_the_encoder_and_the_critic_loss_does(tmp_path):
    model = _model(tmp_path, shared=True)
    before = _extractor_params(model)
    mu_before = model.actor.mu.weight.detach().clone()
    for group in model.critic.optimizer.param_groups:
        group["lr"] = 0.0
    model._update_learning_rate = lambda optimizers: None  # SB3 would reset every optimiser's rate each step
    model.train(gradient_steps=3, batch_size=16)
    after = _extractor_params(model)
    assert all(torch.equal(before[n], after[n]) for n in before), "the actor (or the temperature) trained the encoder"
    assert not torch.equal(mu_before, model.actor.mu.weight), "the actor did not learn"
    for group in model.critic.optimizer.param_groups:
        group["lr"] = 1e-3
    model.train(gradient_steps=3, batch_size=16)
    moved = _extractor_params(model)
    assert any(not torch.equal(after[n], moved[n]) for n in after), "the critic loss did not train the encoder"


def test_a_gradient_step_runs_the_encoder_twice_instead_of_five_times(tmp_path):
    counts = {}
    for shared in (False, True):
        model = _model(tmp_path / str(shared), shared=shared)
        calls = []
        extractors = {model.actor.features_extractor, model.critic.features_extractor,
                      model.critic_target.features_extractor}
        hooks = [e.register_forward_hook(lambda *a: calls.append(1)) for e in extractors]
        model.train(gradient_steps=1, batch_size=16)
        for h in hooks:
            h.remove()
        counts[shared] = len(calls)
    assert counts == {False: 5, True: 2}


def test_the_shared_encoder_step_learns_a_bandit(tmp_path):
    # The reward is the first action coordinate: SAC must push it to the top of its range.
    model = _model(tmp_path, shared=True)
    model.learn(total_timesteps=300)
    obs = {k: v[None] for k, v in TinyCameraEnv().reset(seed=1)[0].items()}
    assert model.predict(obs, deterministic=True)[0][0, 0] > 0.8


def test_a_saved_shared_encoder_model_loads_and_keeps_its_update(tmp_path):
    model = _model(tmp_path, shared=True)
    model.save(tmp_path / "model.zip")
    loaded = SAC.load(tmp_path / "model.zip", env=_vec(), device="cpu")
    assert isinstance(loaded.policy, SharedEncoderPolicy)
    assert loaded.policy.critic.features_extractor is loaded.policy.actor.features_extractor
    obs = {k: v[None] for k, v in TinyCameraEnv().reset(seed=3)[0].items()}
    np.testing.assert_allclose(loaded.predict(obs, deterministic=True)[0], model.predict(obs, deterministic=True)[0],
                               atol=1e-6)


def test_both_ways_of_sharing_at_once_are_refused():
    with pytest.raises(ValueError, match="pick one"):
        RLConfig(shared_encoder=True, share_features_extractor=True)


def test_the_image_presets_share_the_encoder_and_the_state_preset_keeps_sb3s_layout(tmp_path):
    assert RLConfig.from_preset("light").shared_encoder and RLConfig.from_preset("paper").shared_encoder
    # A plain RLConfig() is the light preset without its learnability settings (LEARNABLE) and its overlapped env:
    # those are the presets' choices, not the dataclass defaults.
    plain, light = RLConfig().to_dict(), RLConfig.from_preset("light").to_dict()
    assert RLConfig().preset == "light"
    assert {k: light[k] for k in light if light[k] != plain[k]} == dict(
        terminate_on_success=True, obs_norm=["state", "ft"], action_scale=0.5, overlap_env=True)
    assert not RLConfig.from_preset("state").shared_encoder  # the comparison's runs: SB3's layout
