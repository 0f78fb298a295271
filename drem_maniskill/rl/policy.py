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


class MultimodalExtractor(BaseFeaturesExtractor):
    """Dict obs -> one feature vector: camera CNNs, F/T MLP, state passed through."""

    def __init__(self, observation_space: gym.spaces.Dict, cnn_channels=(16, 32, 32), camera_features: int = 64,
                 ft_features: int = 32):
        encoders, total = {}, 0
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
                encoders[key] = nn.Sequential(nn.Flatten(), nn.Linear(n, 64), nn.ReLU(), nn.Linear(64, ft_features), nn.ReLU())
                total += ft_features
            else:
                encoders[key], total = nn.Flatten(), total + int(torch.tensor(space.shape).prod())
        super().__init__(observation_space, features_dim=total)
        self.encoders = nn.ModuleDict(encoders)

    def forward(self, observations: dict) -> torch.Tensor:
        """Concatenated features ``[B, features_dim]``."""
        return torch.cat([enc(observations[key]) for key, enc in self.encoders.items()], dim=1)
