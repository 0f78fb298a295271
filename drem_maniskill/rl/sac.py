"""SB3's SAC, plus a shared-encoder update for image policies (``RLConfig.shared_encoder``).

With SB3's default each of the actor, the critic and the critic target owns a features extractor,
and one gradient step runs the camera CNNs five times forward and three times backward (the
actor's loss also backpropagates through the critic's CNN). ``SharedEncoderPolicy`` gives actor and
critics one extractor trained by the critic loss only; the actor reads its features detached, as
ManiSkill's ``sac_rgbd.py`` shares one encoder and DrQ / SAC-AE stop the actor's gradient at it.
``SAC.train`` then encodes a batch twice (observations with gradient, next observations without)
and backpropagates once. The target critic keeps SB3's Polyak-averaged Q-networks and reads the
online encoder's features, as ``sac_rgbd.py`` does.

``SAC`` is SB3's class where the policy is SB3's own, so models saved before this module load and
train as they did. ``SAC.train_while_env_steps`` overlaps the gradient step with the env step of a
``rl.vec_env.SubprocDictVecEnv`` (``RLConfig.overlap_env``).
"""

from __future__ import annotations

from typing import Optional

import numpy as np
import stable_baselines3
import torch as th
from stable_baselines3.common.utils import polyak_update
from stable_baselines3.sac.policies import LOG_STD_MAX, LOG_STD_MIN, MultiInputPolicy
from torch.nn import functional as F


class SharedEncoderPolicy(MultiInputPolicy):
    """SB3's ``MultiInputPolicy`` with one features extractor for actor and critic, in the critic's optimiser only."""

    def __init__(self, *args, **kwargs):
        if kwargs.pop("share_features_extractor", True) is not True:
            raise ValueError("SharedEncoderPolicy always shares its features extractor")
        super().__init__(*args, share_features_extractor=True, **kwargs)

    def _build(self, lr_schedule) -> None:
        super()._build(lr_schedule)
        # SB3's sharing trains the extractor through the actor; here the critic owns it.
        actor_params = [p for name, p in self.actor.named_parameters() if not name.startswith("features_extractor.")]
        self.actor.optimizer = self.optimizer_class(actor_params, lr=lr_schedule(1), **self.optimizer_kwargs)
        self.critic.optimizer = self.optimizer_class(self.critic.parameters(), lr=lr_schedule(1),
                                                     **self.optimizer_kwargs)


def _q_values(critic, features: th.Tensor, actions: th.Tensor) -> th.Tensor:
    """``[B, n_critics]`` Q-values of ``critic``'s Q-networks on already extracted features."""
    x = th.cat([features, actions], dim=1)
    return th.cat([q(x) for q in critic.q_networks], dim=1)


def _action_log_prob(actor, features: th.Tensor) -> tuple[th.Tensor, th.Tensor]:
    """SB3's ``Actor.action_log_prob`` from features instead of observations."""
    latent = actor.latent_pi(features)
    log_std = th.clamp(actor.log_std(latent), LOG_STD_MIN, LOG_STD_MAX)
    return actor.action_dist.log_prob_from_params(actor.mu(latent), log_std)


class SAC(stable_baselines3.SAC):
    """SB3's SAC; with a ``SharedEncoderPolicy`` its gradient step encodes each batch once (module docstring)."""

    policy_aliases = {**stable_baselines3.SAC.policy_aliases, "SharedEncoderPolicy": SharedEncoderPolicy}

    # Matrix products of the gradient step in bfloat16 (``RLConfig.train_bf16``; parameters, Adam and the
    # rollouts stay float32). Saved with the model; models saved before the attribute existed train in float32.
    train_bf16: bool = False

    # Gradient steps waiting for the next env step (``train_while_env_steps``); None: SB3's order.
    _deferred: Optional[list] = None

    def _excluded_save_params(self) -> list[str]:
        # A loaded model defers only once train_while_env_steps hooks it to an env again.
        return [*super()._excluded_save_params(), "_deferred"]

    def train_while_env_steps(self, venv) -> None:
        """Run each gradient step while ``venv`` (a ``SubprocDictVecEnv``) takes the next env step in its child process.

        SB3 trains after storing a transition and before choosing the next action; here that
        ``train`` call is kept and made inside the next ``step_wait``, after the action has been sent.
        The updates, their number and their batches (sampled from every stored transition) are SB3's;
        the one difference is that each action comes from the policy one update older. On two cores
        the step then costs about max(env step, gradient step) instead of their sum.
        """
        self._deferred = []
        venv.while_stepping = self._run_deferred

    def _run_deferred(self) -> None:
        pending, self._deferred = self._deferred, None  # train() below runs instead of deferring
        try:
            for gradient_steps, batch_size in pending:
                self.train(gradient_steps, batch_size)
        finally:
            self._deferred = []

    def learn(self, *args, **kwargs):
        """SB3's ``learn``; with deferred gradient steps, the last one is made before it returns, as SB3 makes it."""
        result = super().learn(*args, **kwargs)
        if self._deferred:
            self._run_deferred()
        return result

    def train(self, gradient_steps: int, batch_size: int = 64) -> None:
        """SB3's ``SAC.train``, or the shared-encoder step when the policy is a ``SharedEncoderPolicy``;
        under bfloat16 autocast where ``train_bf16`` is set; deferred to the next env step after
        ``train_while_env_steps``."""
        if self._deferred is not None:
            self._deferred.append((gradient_steps, batch_size))
            return
        with th.autocast(device_type=self.device.type, dtype=th.bfloat16, enabled=self.train_bf16):
            if not isinstance(self.policy, SharedEncoderPolicy):
                return super().train(gradient_steps, batch_size)
            return self._train_shared(gradient_steps, batch_size)

    def _temperature_step(self, log_prob: th.Tensor, losses: list) -> th.Tensor:
        """The step's entropy coefficient; a learned one takes its own step (its loss appended to ``losses``)."""
        if self.ent_coef_optimizer is None or self.log_ent_coef is None:
            return self.ent_coef_tensor
        ent_coef = th.exp(self.log_ent_coef.detach())
        ent_coef_loss = -(self.log_ent_coef * (log_prob + self.target_entropy).detach()).mean()
        losses.append(ent_coef_loss.item())
        self.ent_coef_optimizer.zero_grad()
        ent_coef_loss.backward()
        self.ent_coef_optimizer.step()
        return ent_coef

    def _train_shared(self, gradient_steps: int, batch_size: int) -> None:
        """The shared-encoder gradient steps (module docstring)."""
        if self.use_sde:
            raise ValueError("the shared-encoder SAC step does not support gSDE (use_sde=True)")
        self.policy.set_training_mode(True)
        optimizers = [self.actor.optimizer, self.critic.optimizer]
        if self.ent_coef_optimizer is not None:
            optimizers += [self.ent_coef_optimizer]
        self._update_learning_rate(optimizers)
        actor, critic, encoder = self.actor, self.critic, self.actor.features_extractor
        ent_coef_losses, ent_coefs, actor_losses, critic_losses = [], [], [], []
        for gradient_step in range(gradient_steps):
            data = self.replay_buffer.sample(batch_size, env=self._vec_normalize_env)
            discounts = data.discounts if data.discounts is not None else self.gamma
            features = actor.extract_features(data.observations, encoder)
            with th.no_grad():
                next_features = actor.extract_features(data.next_observations, encoder)
                next_actions, next_log_prob = _action_log_prob(actor, next_features)
                next_q, _ = _q_values(self.critic_target, next_features, next_actions).min(dim=1, keepdim=True)

            # The actor and the temperature read the encoder's features without training it.
            detached = features.detach()
            actions_pi, log_prob = _action_log_prob(actor, detached)
            log_prob = log_prob.reshape(-1, 1)
            ent_coef = self._temperature_step(log_prob, ent_coef_losses)
            ent_coefs.append(ent_coef.item())

            target_q = data.rewards + (1 - data.dones) * discounts * (next_q - ent_coef * next_log_prob.reshape(-1, 1))
            current_q = _q_values(critic, features, data.actions)
            critic_loss = 0.5 * sum(F.mse_loss(current_q[:, i : i + 1], target_q) for i in range(current_q.shape[1]))
            critic_losses.append(critic_loss.item())
            critic.optimizer.zero_grad()
            critic_loss.backward()
            critic.optimizer.step()

            min_q_pi, _ = _q_values(critic, detached, actions_pi).min(dim=1, keepdim=True)
            actor_loss = (ent_coef * log_prob - min_q_pi).mean()
            actor_losses.append(actor_loss.item())
            actor.optimizer.zero_grad()
            actor_loss.backward()
            actor.optimizer.step()

            if gradient_step % self.target_update_interval == 0:
                polyak_update(self.critic.parameters(), self.critic_target.parameters(), self.tau)
                polyak_update(self.batch_norm_stats, self.batch_norm_stats_target, 1.0)

        self._n_updates += gradient_steps
        self.logger.record("train/n_updates", self._n_updates, exclude="tensorboard")
        self.logger.record("train/ent_coef", np.mean(ent_coefs))
        self.logger.record("train/actor_loss", np.mean(actor_losses))
        self.logger.record("train/critic_loss", np.mean(critic_losses))
        if ent_coef_losses:
            self.logger.record("train/ent_coef_loss", np.mean(ent_coef_losses))
