"""The RL algorithms a run can use, as one table: ``ALGOS[config.algo]`` builds, saves and loads the learner.

SAC (stable-baselines3) is the one algorithm today. Adding one is an entry here: how to build it
from an ``RLConfig`` and an SB3 ``VecEnv``, and its class (for ``load``). Off-policy algorithms
also save and restore their replay buffer, so a resumed run continues where it stopped.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Callable

from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.off_policy_algorithm import OffPolicyAlgorithm

from drem_maniskill.rl.policy import MultimodalExtractor
from drem_maniskill.rl.sac import SAC


def policy_kwargs(config) -> dict:
    """SB3 ``policy_kwargs``: our multimodal extractor and the config's network sizes."""
    return dict(
        features_extractor_class=MultimodalExtractor,
        features_extractor_kwargs=dict(cnn_channels=config.cnn_channels, camera_features=config.camera_features,
                                       ft_features=config.ft_features,
                                       normalize=config.normalized_inputs),
        net_arch=list(config.net_arch),
        # SharedEncoderPolicy always shares, through the critic; SB3's own sharing trains through the actor.
        **({} if config.shared_encoder else dict(share_features_extractor=config.share_features_extractor)),
    )


def build_sac(config, venv) -> SAC:
    """A fresh SAC (``rl.sac``: SB3's, shared-encoder step optional) with our extractor, as ``config`` says."""
    model = SAC(
        "SharedEncoderPolicy" if config.shared_encoder else "MultiInputPolicy", venv,
        learning_rate=config.learning_rate,
        # No more transitions than steps: SB3 allocates (and pickles) the whole buffer.
        buffer_size=min(config.buffer_size, config.steps), batch_size=config.batch_size,
        learning_starts=config.learning_starts, train_freq=config.train_freq, gradient_steps=config.gradient_steps,
        gamma=config.gamma, tau=config.tau, ent_coef=config.ent_coef, seed=config.seed, device=config.device,
        policy_kwargs=policy_kwargs(config),
    )
    model.train_bf16 = config.train_bf16
    return model


@dataclass(frozen=True)
class AlgoSpec:
    """An SB3 algorithm: its class and how to build it from a config and a VecEnv."""

    cls: type
    build: Callable

    def save(self, model: BaseAlgorithm, folder: Path) -> None:
        """Write ``model.zip`` (and ``replay_buffer.pkl`` for an off-policy algorithm) into ``folder``."""
        model.save(folder / "model.zip")
        if isinstance(model, OffPolicyAlgorithm):
            model.save_replay_buffer(folder / "replay_buffer.pkl")

    def load(self, folder: Path, venv, device) -> BaseAlgorithm:
        """The model saved in ``folder`` by ``save``, attached to ``venv``."""
        model = self.cls.load(folder / "model.zip", env=venv, device=device)
        if isinstance(model, OffPolicyAlgorithm) and (folder / "replay_buffer.pkl").exists():
            model.load_replay_buffer(folder / "replay_buffer.pkl")
        return model


ALGOS: dict[str, AlgoSpec] = {
    "sac": AlgoSpec(SAC, build_sac),
}


def algo_spec(name: str) -> AlgoSpec:
    """The ``ALGOS`` entry of ``name``, or a ValueError listing the choices."""
    if name not in ALGOS:
        raise ValueError(f"unknown algorithm {name!r}; choose one of: {', '.join(ALGOS)}")
    return ALGOS[name]
