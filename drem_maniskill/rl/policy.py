"""The policy's features extractor: a small CNN per camera, an MLP on the F/T history, the state as is.

Modelled on the DREM encoder (Section III-B: a stride-2 CNN and a linear layer per camera, the
F/T history to a small vector), as the paper does for its policy. SB3's ``NatureCNN`` needs at
least 36 px images, so the 32 px light preset needs its own extractor anyway.
"""

from __future__ import annotations

import gymnasium as gym
import torch
from stable_baselines3.common.torch_layers import BaseFeaturesExtractor
from torch import nn


class RunningNorm(nn.Module):
    """``(x - mean) / std``, clipped to +-``clip``, with the mean and variance of every batch seen in training mode.

    The buffers are named like BatchNorm's (``running_mean``, ``running_var``): SB3's SAC copies
    those from the critic to its target network, so both normalise alike. Unlike BatchNorm it
    always normalises with the running statistics, in training as in evaluation.
    """

    def __init__(self, shape, clip: float = 10.0, eps: float = 1e-8):
        super().__init__()
        self.clip, self.eps = float(clip), float(eps)
        self.register_buffer("running_mean", torch.zeros(shape))
        self.register_buffer("running_var", torch.ones(shape))
        self.register_buffer("count", torch.zeros(()))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """Normalised ``x``; in training mode the statistics first take in this batch (Chan's parallel update)."""
        if self.training:
            with torch.no_grad():
                n = x.shape[0]
                mean, var = x.mean(0), x.var(0, unbiased=False)
                total = self.count + n
                delta = mean - self.running_mean
                m2 = self.running_var * self.count + var * n + delta**2 * self.count * n / total
                self.running_mean += delta * n / total
                self.running_var.copy_(m2 / total)
                self.count.fill_(total)
        return ((x - self.running_mean) / torch.sqrt(self.running_var + self.eps)).clamp(-self.clip, self.clip)


class MultimodalExtractor(BaseFeaturesExtractor):
    """Dict obs -> one feature vector: camera CNNs, F/T MLP, state passed through.

    ``normalize`` names the vector inputs (``state``, ``ft``) that go through a ``RunningNorm``
    first: the state holds positions in metres, where a millimetre of clearance is 0.001.
    """

    def __init__(self, observation_space: gym.spaces.Dict, cnn_channels=(16, 32, 32), camera_features: int = 64,
                 ft_features: int = 32, normalize: tuple = ()):
        encoders, total = {}, 0
        unknown = set(normalize) - {k for k, s in observation_space.spaces.items() if len(s.shape) != 3}
        if unknown:
            raise ValueError(f"can only normalise the policy's vector inputs, not {sorted(unknown)}")
        for key, space in observation_space.spaces.items():
            if len(space.shape) == 3:  # a camera, [3, S, S] uint8 (SB3 scales it to [0, 1])
                layers, c, side = [], space.shape[0], space.shape[1]
                for width in cnn_channels:
                    layers += [nn.Conv2d(c, width, 3, stride=2, padding=1), nn.ReLU()]
                    c, side = width, (side + 1) // 2
                layers += [nn.Flatten(), nn.Linear(c * side * side, camera_features), nn.ReLU()]
                encoders[key], total = nn.Sequential(*layers), total + camera_features
            elif key == "ft":
                n = int(torch.tensor(space.shape).prod())
                encoders[key] = nn.Sequential(nn.Flatten(), nn.Linear(n, 64), nn.ReLU(), nn.Linear(64, ft_features),
                                              nn.ReLU())
                total += ft_features
            else:
                encoders[key], total = nn.Flatten(), total + int(torch.tensor(space.shape).prod())
            if key in normalize:
                inner = encoders[key]
                layers = inner if isinstance(inner, nn.Sequential) else [inner]
                encoders[key] = nn.Sequential(RunningNorm(space.shape), *layers)
        super().__init__(observation_space, features_dim=total)
        self.encoders = nn.ModuleDict(encoders)

    def forward(self, observations: dict) -> torch.Tensor:
        """Concatenated features ``[B, features_dim]``."""
        return torch.cat([enc(observations[key]) for key, enc in self.encoders.items()], dim=1)
