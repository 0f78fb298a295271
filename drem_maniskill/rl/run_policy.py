"""The policy of a ``train-policy`` run folder: its newest checkpoint, loaded to act in ``experts.rollout``.

``load_policy(run)`` is the one place a trained policy is read back: ``check-reward``, the policy rounds of a build
and the experiments that roll a run's policy out all call it. ``train_policy`` writes what it reads
(``checkpoints/latest.json`` pointing at ``checkpoints/step_N/model.zip``); a resumed run reloads its model with its
replay buffer through ``rl.algos`` instead, since it trains on.
"""

from __future__ import annotations

import dataclasses
import json
from dataclasses import dataclass
from pathlib import Path
from typing import Optional

import torch

from drem_maniskill.rl.algos import algo_spec
from drem_maniskill.rl.config import RLConfig


def latest_checkpoint(run_dir) -> Optional[Path]:
    """The newest complete checkpoint folder of a run, or None."""
    latest = Path(run_dir) / "checkpoints" / "latest.json"
    if not latest.exists():
        return None
    folder = latest.parent / json.loads(latest.read_text())["dir"]
    return folder if folder.exists() else None


def _policy(model, deterministic: bool):
    """``policy(obs) -> action`` of an SB3 model on our dict observations (torch in, torch out)."""

    def act(obs):
        action, _ = model.predict({k: v.cpu().numpy() for k, v in obs.items()}, deterministic=deterministic)
        return torch.as_tensor(action, dtype=torch.float32)

    return act


def deterministic_policy(model):
    """``policy(obs) -> action`` of an SB3 model's mean action on our dict observations, for ``rollout``."""
    return _policy(model, deterministic=True)


@dataclass
class TrainedPolicy:
    """A finished run's policy: the SB3 model of its newest checkpoint, the run's config, that checkpoint's folder."""

    model: object
    config: RLConfig
    checkpoint: Path

    def act(self, deterministic: bool = True, seed: Optional[int] = None):
        """``policy(obs) -> action`` for ``rollout``: the mean action, or sampled actions (``deterministic=False``,
        which visit more than the mean action does) after seeding torch's global generator, which SB3 samples with."""
        if seed is not None:
            torch.manual_seed(seed)
        return _policy(self.model, deterministic)


def load_policy(run, device: str = "cpu") -> TrainedPolicy:
    """The policy of the run folder ``run`` (its newest checkpoint) with the run's ``RLConfig``, ``out`` set to
    ``run`` (where the folder is now, wherever it was trained)."""
    folder = Path(run)
    if not (folder / "config.json").is_file():
        raise FileNotFoundError(f"{folder} is not a train-policy run (no config.json); pass a run folder such as "
                                f"outputs/rl_image/PegInHole-v1/drem/seed0")
    config = dataclasses.replace(RLConfig.load(folder / "config.json"), out=str(folder))
    checkpoint = latest_checkpoint(folder)
    if checkpoint is None:
        raise FileNotFoundError(f"{folder} holds no policy checkpoint (a run whose training saved none, or one kept "
                                "without its checkpoints); train it with `drem-maniskill train-policy`, then load it")
    # The policy alone: a replay buffer is only for training on.
    model = algo_spec(config.algo).cls.load(checkpoint / "model.zip", device=device)
    return TrainedPolicy(model, config, checkpoint)
