"""The multimodal encoder-decoder of DREM (Section III-B of the paper).

Encoder: per 128x128x3 image a 6-layer CNN and a fully connected layer to 64-d; the 8x6 F/T
history through a 4-layer causal 1-d convolution to 32-d; the concatenation through a 2-layer
MLP to the 128-d latent ``h(s)``. Decoder: a 7-layer transposed CNN back to each image and a
3-layer 1-d transposed convolution back to the 8x6 F/T history. Which inputs are used is a
config (``modalities``), so the paper's "Image learned" baseline is this model without F/T.

Beyond the paper, ``poses``: every body's pose and the robot's joint positions, read from the simulator's state
(``utils.state.scene_poses``), through an MLP to 64-d and back. It is for tasks whose objects are too small in the
cameras to be read (a 4 cm cube is a few pixels at 64 px): the latent can then place the objects, not only the arm.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import torch
import torch.nn.functional as F
from torch import nn

from drem_maniskill.drem.checkpoint import CheckpointError

MODALITIES = ("fixed", "wrist", "ft", "poses")
VECTOR_MODALITIES = ("ft", "poses")
INITS = ("kaiming", "torch")
MIN_NORMALISER = 0.01
"""Smallest ``d(h(s_0), h(s_G))`` a reward may divide by. Trained rewards measure 1.1-2.0; a collapsed encoder, whose
latents all point the same way, gives about 1e-5, and its reward then swings by thousands on any state."""
LEAKY_SLOPE = 0.1
CAMERA_OF = {"fixed": "fixed_camera", "wrist": "wrist_camera"}


@dataclass
class ModelConfig:
    """Architecture; defaults are the paper's."""

    modalities: tuple = ("fixed", "wrist", "ft")
    """Inputs: the fixed camera, the wrist camera and the wrist F/T history (``ft``); without ``ft``, image-only.
    ``poses`` (beyond the paper): the scene's poses from the sim state."""
    image_size: int = 128
    """Side of the square images the encoder takes, in pixels (a multiple of 64)."""
    ft_history: int = 8
    """F/T readings per observation (a multiple of 4)."""
    image_dim: int = 64
    """Features per camera after its CNN."""
    ft_dim: int = 32
    """Features of the F/T history after its causal convolutions."""
    poses_size: int = 0
    """Values in the scene-poses vector (``poses``); set from the progress tree when the model is trained."""
    poses_dim: int = 64
    """Features of the scene poses after their MLP."""
    poses_relative: bool = False
    """Beyond the paper: the pairwise position differences of the scene's actors are inputs too, beside the poses
    (where one object is relative to another reads the same at every placement)."""
    poses_actors: int = 0
    """Actors at the head of the scene-poses vector (``poses_relative``); set from the progress tree's env."""
    latent_dim: int = 128
    """Size of the latent ``h(s)``."""
    channels: tuple = (16, 32, 32, 64, 64, 128)
    """Channels of the six stride-2 conv layers of each image encoder."""
    init: str = "kaiming"
    """Weight init: ``kaiming`` (He init for LeakyReLU(0.1), zero biases) or ``torch`` (PyTorch's layer defaults).
    With PyTorch's defaults the image encoders' outputs barely depend on the image, every latent points the same
    way, ``d(h(s_0), h(s_G))`` starts near 1e-5 and a short training never leaves that point."""

    def __post_init__(self):
        self.modalities = tuple(self.modalities)
        self.channels = tuple(self.channels)
        unknown = [m for m in self.modalities if m not in MODALITIES]
        if unknown or not self.modalities:
            raise ValueError(f"modalities must be a non-empty subset of {MODALITIES}, got {self.modalities}")
        if self.init not in INITS:
            raise ValueError(f"init must be one of {INITS}, got {self.init!r}")
        if self.image_size % 64:
            raise ValueError(f"image_size must be a multiple of 64 (6 stride-2 layers), got {self.image_size}")

    @property
    def cameras(self) -> tuple:
        """Image modalities in a fixed order."""
        return tuple(m for m in self.modalities if m not in VECTOR_MODALITIES)

    def to_dict(self) -> dict:
        """JSON-ready dict."""
        return asdict(self)

    @classmethod
    def from_dict(cls, d: dict) -> "ModelConfig":
        """The config a checkpoint header or recipe records; one without ``init`` was trained from PyTorch's init."""
        return cls(**{"init": "torch", **d})


class ImageEncoder(nn.Module):
    """6 stride-2 conv layers (128 -> 2 pixels) and a linear layer to ``out_dim``."""

    def __init__(self, channels, out_dim, image_size):
        super().__init__()
        layers, c_in = [], 3
        for c in channels:
            layers += [nn.Conv2d(c_in, c, 4, stride=2, padding=1), nn.LeakyReLU(0.1)]
            c_in = c
        self.conv = nn.Sequential(*layers)
        self.side = image_size // 2 ** len(channels)
        self.fc = nn.Linear(c_in * self.side**2, out_dim)

    def forward(self, x):
        """``[B, 3, H, W]`` floats in [0, 1] -> ``[B, out_dim]``."""
        return self.fc(self.conv(x.contiguous(memory_format=torch.channels_last)).flatten(1))


class ImageDecoder(nn.Module):
    """Linear layer to a 2x2 map, 6 stride-2 transposed convs and a last 1-stride one: 7 layers."""

    def __init__(self, channels, in_dim, image_size):
        super().__init__()
        rev = tuple(reversed(channels))
        self.side = image_size // 2 ** len(channels)
        self.fc = nn.Linear(in_dim, rev[0] * self.side**2)
        layers = []
        for c_in, c_out in zip(rev, rev[1:] + (rev[-1],)):
            layers += [nn.ConvTranspose2d(c_in, c_out, 4, stride=2, padding=1), nn.LeakyReLU(0.1)]
        layers.append(nn.ConvTranspose2d(rev[-1], 3, 3, stride=1, padding=1))
        self.deconv = nn.Sequential(*layers)
        self.c0 = rev[0]

    def forward(self, h):
        """``[B, in_dim]`` -> image logits ``[B, 3, H, W]``."""
        # Channels-last: on the CPU the transposed convolutions, most of a training step, run ~1.7x faster so.
        x = self.fc(h).view(h.shape[0], self.c0, self.side, self.side).contiguous(memory_format=torch.channels_last)
        return self.deconv(x)


class CausalConv1d(nn.Conv1d):
    """1-d convolution that only looks at the past (left padding)."""

    def __init__(self, c_in, c_out, kernel_size, dilation=1):
        super().__init__(c_in, c_out, kernel_size, dilation=dilation)
        self.left = (kernel_size - 1) * dilation

    def forward(self, x):
        """``[B, C, T]`` -> ``[B, C', T]``."""
        return super().forward(F.pad(x, (self.left, 0)))


class FTEncoder(nn.Module):
    """4 causal dilated conv layers over the F/T history, then the newest step -> ``out_dim``."""

    def __init__(self, out_dim, history):
        super().__init__()
        self.net = nn.Sequential(
            CausalConv1d(6, 16, 2, 1), nn.LeakyReLU(0.1),
            CausalConv1d(16, 32, 2, 2), nn.LeakyReLU(0.1),
            CausalConv1d(32, 64, 2, 4), nn.LeakyReLU(0.1),
            CausalConv1d(64, out_dim, 2, 8),
        )

    def forward(self, ft):
        """``[B, T, 6]`` (scaled) -> ``[B, out_dim]``: the receptive field of the last step covers all 8."""
        return self.net(ft.transpose(1, 2))[:, :, -1]


class FTDecoder(nn.Module):
    """3 transposed 1-d conv layers: latent -> ``[B, history, 6]``."""

    def __init__(self, in_dim, history):
        super().__init__()
        self.start = history // 4
        self.fc = nn.Linear(in_dim, 64 * self.start)
        self.net = nn.Sequential(
            nn.ConvTranspose1d(64, 32, 4, stride=2, padding=1), nn.LeakyReLU(0.1),
            nn.ConvTranspose1d(32, 16, 4, stride=2, padding=1), nn.LeakyReLU(0.1),
            nn.ConvTranspose1d(16, 6, 3, stride=1, padding=1),
        )

    def forward(self, h):
        """``[B, in_dim]`` -> ``[B, history, 6]``."""
        return self.net(self.fc(h).view(h.shape[0], 64, self.start)).transpose(1, 2)


class PosesEncoder(nn.Module):
    """Standardised scene poses through a 3-layer MLP -> ``out_dim``."""

    def __init__(self, size, out_dim):
        super().__init__()
        self.net = nn.Sequential(nn.Linear(size, 256), nn.LeakyReLU(0.1), nn.Linear(256, 256), nn.LeakyReLU(0.1),
                                 nn.Linear(256, out_dim))

    def forward(self, poses):
        """``[B, size]`` (standardised) -> ``[B, out_dim]``."""
        return self.net(poses)


class PosesDecoder(nn.Module):
    """2-layer MLP: latent -> standardised scene poses."""

    def __init__(self, in_dim, size):
        super().__init__()
        self.net = nn.Sequential(nn.Linear(in_dim, 256), nn.LeakyReLU(0.1), nn.Linear(256, size))

    def forward(self, h):
        """``[B, in_dim]`` -> ``[B, size]``."""
        return self.net(h)


class DREMModel(nn.Module):
    """Encoder ``h(s)`` and decoders. Inputs: dict of uint8 images ``[B, H, W, 3]`` and ``ft [B, T, 6]``."""

    def __init__(self, config: ModelConfig, ft_scale: float = 10.0):
        super().__init__()
        self.config = config
        # F/T in newtons spans 0-100; a fixed scale keeps the conv inputs near unit size.
        self.register_buffer("ft_scale", torch.tensor(float(ft_scale)))
        self.image_encoders = nn.ModuleDict(
            {c: ImageEncoder(config.channels, config.image_dim, config.image_size) for c in config.cameras}
        )
        self.image_decoders = nn.ModuleDict(
            {c: ImageDecoder(config.channels, config.latent_dim, config.image_size) for c in config.cameras}
        )
        fused = config.image_dim * len(config.cameras)
        if "ft" in config.modalities:
            if config.ft_history % 4:
                raise ValueError(f"ft_history must be a multiple of 4 for the decoder, got {config.ft_history}")
            self.ft_encoder = FTEncoder(config.ft_dim, config.ft_history)
            self.ft_decoder = FTDecoder(config.latent_dim, config.ft_history)
            fused += config.ft_dim
        if "poses" in config.modalities:
            if config.poses_size < 1:
                raise ValueError("a model reading poses needs poses_size (the scene-poses vector's length); "
                                 "train_reward sets it from the progress tree")
            if config.poses_relative and not 2 <= config.poses_actors <= config.poses_size // 7:
                raise ValueError(f"poses_relative needs at least two actors in the poses vector, got poses_actors="
                                 f"{config.poses_actors}; train_reward sets it from the progress tree's env")
            size = poses_features(torch.zeros(1, config.poses_size), config).shape[1]
            # Standardised with the tree's own statistics (set_poses_stats): positions differ by centimetres,
            # joint angles by radians, and some bodies never move.
            self.register_buffer("poses_mean", torch.zeros(size))
            self.register_buffer("poses_std", torch.ones(size))
            self.poses_encoder = PosesEncoder(size, config.poses_dim)
            self.poses_decoder = PosesDecoder(config.latent_dim, size)
            fused += config.poses_dim
        self.fusion = nn.Sequential(nn.Linear(fused, 256), nn.LeakyReLU(0.1), nn.Linear(256, config.latent_dim))
        if config.init == "kaiming":
            kaiming_init(self)

    def prepare(self, batch: dict) -> dict:
        """uint8 images ``[B, H, W, 3]`` -> floats ``[B, 3, H, W]`` in [0, 1]; F/T scaled."""
        out = {}
        for c in self.config.cameras:
            img = batch[c]
            if img.dtype == torch.uint8:
                img = img.float() / 255.0
            if img.shape[-1] == 3:
                img = img.permute(0, 3, 1, 2)
            if img.shape[-1] != self.config.image_size or img.shape[-2] != self.config.image_size:
                # Same resampling as the training data (TreeDataset): area when shrinking.
                mode = "area" if img.shape[-1] > self.config.image_size else "bilinear"
                img = F.interpolate(img, size=(self.config.image_size,) * 2, mode=mode)
            out[c] = img.contiguous()
        if "ft" in self.config.modalities:
            out["ft"] = batch["ft"].float() / self.ft_scale
        if "poses" in self.config.modalities:
            out["poses"] = (poses_features(batch["poses"].float(), self.config) - self.poses_mean) / self.poses_std
        return out

    def set_poses_stats(self, poses: torch.Tensor, floor: float = 0.01) -> None:
        """Standardise scene poses by the mean and spread of ``poses`` ``[N, size]`` (the training set's); a spread
        below ``floor`` counts as ``floor``, so a body that never moved in the tree does not blow up elsewhere."""
        features = poses_features(poses.float(), self.config)
        self.poses_mean.copy_(features.mean(0))
        self.poses_std.copy_(features.std(0).clamp_min(floor))

    def encode(self, inputs: dict) -> torch.Tensor:
        """Prepared inputs -> latent ``[B, latent_dim]``."""
        parts = [self.image_encoders[c](inputs[c]) for c in self.config.cameras]
        if "ft" in self.config.modalities:
            parts.append(self.ft_encoder(inputs["ft"]))
        if "poses" in self.config.modalities:
            parts.append(self.poses_encoder(inputs["poses"]))
        return self.fusion(torch.cat(parts, dim=1))

    def decode(self, h: torch.Tensor) -> dict:
        """Latent -> image logits per camera, the scaled F/T history and the standardised poses."""
        out = {c: self.image_decoders[c](h) for c in self.config.cameras}
        if "ft" in self.config.modalities:
            out["ft"] = self.ft_decoder(h)
        if "poses" in self.config.modalities:
            out["poses"] = self.poses_decoder(h)
        return out

    def forward(self, batch: dict):
        """Raw batch -> (latent, reconstruction, prepared inputs)."""
        inputs = self.prepare(batch)
        h = self.encode(inputs)
        return h, self.decode(h), inputs


def poses_features(poses: torch.Tensor, config: ModelConfig) -> torch.Tensor:
    """The pose model's input before standardising: the scene poses ``[B, size]`` and, with ``poses_relative``, each
    pair of the first ``poses_actors`` actors' position differences (``scene_poses`` puts each actor's pose first,
    7 values: position then quaternion)."""
    if not config.poses_relative:
        return poses
    positions = poses[:, : 7 * config.poses_actors].reshape(len(poses), config.poses_actors, 7)[..., :3]
    i, j = torch.triu_indices(config.poses_actors, config.poses_actors, offset=1)
    return torch.cat([poses, (positions[:, i] - positions[:, j]).flatten(1)], dim=1)


def kaiming_init(module: nn.Module, slope: float = LEAKY_SLOPE) -> None:
    """He-normal weights for LeakyReLU(``slope``) and zero biases on every conv and linear layer of ``module``."""
    for m in module.modules():
        if isinstance(m, (nn.Conv1d, nn.Conv2d, nn.ConvTranspose1d, nn.ConvTranspose2d, nn.Linear)):
            nn.init.kaiming_normal_(m.weight, a=slope, nonlinearity="leaky_relu")
            if m.bias is not None:
                nn.init.zeros_(m.bias)


def cosine_distance(h: torch.Tensor, h_goal: torch.Tensor) -> torch.Tensor:
    """``1 - <h_bar, h_bar_G>`` with L2-normalised vectors (the paper's latent distance)."""
    return 1.0 - (F.normalize(h, dim=-1) * F.normalize(h_goal, dim=-1)).sum(-1)


class DegenerateRewardError(CheckpointError):
    """The expert's start and goal embed to nearly the same direction, so ``R(s)`` has no usable normaliser."""


def check_normaliser(h_start: torch.Tensor, h_goal: torch.Tensor, source: str = "this model") -> float:
    """``d(h(s_0), h(s_G))``, or ``DegenerateRewardError`` when it is below ``MIN_NORMALISER`` (or not finite)."""
    value = float(cosine_distance(h_start.reshape(1, -1).float(), h_goal.reshape(1, -1).float())[0])
    if not value >= MIN_NORMALISER:  # also catches NaN
        raise DegenerateRewardError(
            f"{source} is degenerate: d(h(s_0), h(s_G)) = {value:.3g}, below {MIN_NORMALISER}, so the reward "
            "1 - d(h, h_G) / d(h_0, h_G) would divide by almost nothing. The encoder maps the expert's first and last "
            "observations to the same direction: train longer, check that the tree's depths span the task "
            "(`tree_report`), or keep the default `init='kaiming'`."
        )
    return value
