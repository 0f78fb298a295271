"""The DREM reward (Eq. 2 of the paper) as a batched torch module.

``R(s) = 1 - d(h(s), h(s_G)) / d(h(s_0), h(s_G))`` with ``d`` the cosine distance and ``s_0``,
``s_G`` the expert's first and last observations (their embeddings are in the checkpoint).
Observations of ``num_envs`` envs in, a ``[num_envs]`` tensor out, without gradients.
"""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Optional

import torch
from torch import nn

from drem_maniskill.drem.checkpoint import CheckpointError, check_compatible, load_checkpoint
from drem_maniskill.drem.model import CAMERA_OF, DREMModel, ModelConfig, cosine_distance

# rewards/ sits beside the package in a checkout (editable install); a wheel installs it as
# data files under <prefix>/share/drem-maniskill/rewards (pyproject's data-files).
REWARDS_DIRS = (Path(__file__).resolve().parents[2] / "rewards", Path(sys.prefix) / "share" / "drem-maniskill" / "rewards")


def default_checkpoint(env_id: str, image_only: bool = False) -> Path:
    """Path of the shipped checkpoint for ``env_id`` (``rewards/<env_id>/drem.pt``)."""
    name = "drem_image.pt" if image_only else "drem.pt"
    for folder in REWARDS_DIRS:
        if (folder / env_id / name).exists():
            return folder / env_id / name
    return REWARDS_DIRS[0] / env_id / name


class DREMReward(nn.Module):
    """Task progress reward from a DREM checkpoint; call with an observation batch."""

    def __init__(self, header: dict, weights: dict):
        super().__init__()
        self.header = header
        config = ModelConfig(**header["model"])
        self.model = DREMModel(config)
        state = {k[len("model."):]: v for k, v in weights.items() if k.startswith("model.")}
        missing, unexpected = self.model.load_state_dict(state, strict=False)
        if missing or unexpected:
            raise CheckpointError(f"checkpoint weights do not match its model config: missing {missing[:5]}, unexpected {unexpected[:5]}")
        self.register_buffer("h_goal", weights["h_goal"].float())
        self.register_buffer("h_start", weights["h_start"].float())
        self.model.eval()
        self.requires_grad_(False)

    @classmethod
    def from_checkpoint(cls, path: str, env=None) -> "DREMReward":
        """Load ``path``; with ``env`` given, check that the checkpoint fits it first."""
        header, weights = load_checkpoint(path)
        if env is not None:
            u = env.unwrapped
            cams = {uid: (s.config.height, s.config.width) for uid, s in u._sensors.items()}
            ft = getattr(u, "ft_history", None) if hasattr(u, "ft") else None
            env_id = getattr(u, "env_id", "") or (u.spec.id if u.spec else type(u).__name__)
            check_compatible(header, env_id, cams, ft, str(path))
        reward = cls(header, weights)
        if env is not None:
            reward = reward.to(env.unwrapped.device)
        return reward

    @property
    def camera_uids(self) -> list:
        """Camera uids the model reads."""
        return [self.camera_of[c] for c in self.model.config.cameras]

    @property
    def camera_of(self) -> dict:
        """Image modality -> camera uid, as the checkpoint was trained (``base_camera`` on stock tasks)."""
        uids = self.header.get("camera_uids") or [CAMERA_OF[c] for c in self.model.config.cameras]
        return dict(zip(self.model.config.cameras, uids))

    def inputs_from_obs(self, obs: dict) -> dict:
        """Pick the model's inputs from a ManiSkill observation dict (``sensor_data`` + ``extra``)."""
        batch = {c: obs["sensor_data"][self.camera_of[c]]["rgb"] for c in self.model.config.cameras}
        if "ft" in self.model.config.modalities:
            batch["ft"] = obs["extra"]["ft"]
        return batch

    @torch.no_grad()
    def embed(self, batch: dict) -> torch.Tensor:
        """Latent ``h(s)`` ``[B, 128]`` of raw inputs (uint8 images of any size, F/T)."""
        inputs = self.model.prepare(batch)
        first = next(iter(inputs.values()))
        # oneDNN's per-call set-up dominates for a handful of samples on the CPU (measured:
        # 3.3 ms with it, 1.8 ms without, for one env); large batches keep it.
        small_cpu = first.device.type == "cpu" and first.shape[0] < 8
        with torch.backends.mkldnn.flags(enabled=not small_cpu):
            return self.model.encode(inputs)

    @torch.no_grad()
    def forward(self, batch: dict) -> torch.Tensor:
        """``R(s)`` ``[B]`` of raw inputs."""
        h = self.embed(batch)
        scale = cosine_distance(self.h_start[None], self.h_goal[None]).clamp(min=1e-6)
        return 1.0 - cosine_distance(h, self.h_goal[None]) / scale


def resolve_checkpoint(env_id: str, path: Optional[str], image_only: bool = False) -> Path:
    """The checkpoint to use: ``path`` if given, else the shipped default for ``env_id``."""
    if path:
        return Path(path)
    default = default_checkpoint(env_id, image_only)
    if not default.exists():
        raise CheckpointError(
            f"no DREM checkpoint ships for {env_id} (looked for {default}). Train one with "
            f"`drem-maniskill train-reward` and pass gym.make({env_id!r}, reward_mode='drem', drem_checkpoint=PATH)"
        )
    return default
