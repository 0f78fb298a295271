"""VICE-RAQ baseline: a learned success classifier on the camera images as the reward.

Singh et al., "End-to-End Robotic Reinforcement Learning without Reward Engineering", RSS 2019.
A small CNN sees the fixed and the wrist camera (downscaled to ``image_size``) and is trained
with goal examples as positives and the policy's own visited states as negatives; the reward
is its ``log p(success | s)``. Active queries ("RAQ"): every ``query_every`` classifier
updates, the visited states added since the last round that the classifier rates most likely
successful are labelled by the task's ``info["success"]``; true ones join the positives.

Use::

    from drem_maniskill.baselines.vice import VICEConfig, VICERewardWrapper
    from drem_maniskill.experts import collect_goal_examples

    cfg = VICEConfig()
    goals = collect_goal_examples("PegInHole-v1", seeds=range(10))   # or goal_examples_from_h5(path)
    env = VICERewardWrapper(gym.make("PegInHole-v1", obs_mode="rgb"), goals, cfg)
    # ... wrap further (FlattenRGBDObservationWrapper, ManiSkillVectorEnv) on top of this one.

Interface for a trainer (e.g. an SB3 callback), all there is:

* ``env.step`` returns the classifier's log-probability ``[num_envs]`` as the reward, keeps
  the env's reward in ``info["original_reward"]``, and stores every visited state (images
  and success flag) in a ring buffer of ``cfg.buffer_size``;
* every ``cfg.update_every`` env steps call ``metrics = wrapper.update(cfg.train_steps)``
  (gradient steps; active queries run inside on schedule); log the returned dict;
* ``wrapper.state_dict()`` / ``wrapper.load_state_dict(sd)`` checkpoint and restore the
  classifier, its optimiser, the buffers, the counters and the sampling RNG
  (``torch.save``-able);
* ``wrapper.evaluation_env(env)`` rewards another env (an evaluation env) with the same
  classifier, storing nothing.

That is the learned-reward interface of ``drem_maniskill.rl.rewards`` (``LearnedReward``).

Differences from the reference implementation (avisingh599/reward-learning-rl): its VICE
discriminator puts the policy's ``log pi(a|s)`` beside the classifier's logit; the wrapper
does not see the policy, so we train the plain success classifier (its RAQ variant) and use
``log sigmoid(logit)`` as the reward, as the DREM paper describes the baseline.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Optional, Sequence

import gymnasium as gym
import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from drem_maniskill.utils.cameras import camera_images


@dataclass
class VICEConfig:
    """Hyper-parameters; "ref" marks the reference implementation's (VICE-RAQ) value."""

    cameras: tuple = ("fixed_camera", "wrist_camera")
    image_size: int = 64  # ref: 48 px; 64 px keeps the USB key visible in the wrist view
    channels: tuple = (16, 32, 32, 32)  # conv trunk per camera, stride 2 each (ref: 2 conv + max-pool)
    feature_dim: int = 64  # per camera, after the trunk
    hidden_dim: int = 256  # ref: classifier MLP (256, 256)
    lr: float = 1e-4  # ref classifier_lr
    batch_size: int = 128  # positives and negatives each, per gradient step (ref classifier_batch_size)
    mixup_alpha: float = 1.0  # ref mixup_alpha: mixup on images and labels, Beta(1, 1)
    # Gradient steps per update: the ref's 10 per 1000 env steps give 1,500 over the paper's 150k-step
    # runs; ours are 50k steps (the SAC comparison), so 30 per 1000 give the classifier those same 1,500.
    train_steps: int = 30
    update_every: int = 1000  # env steps between updates, for the trainer (ref epoch_length)
    query_every: int = 30  # gradient steps between active-query rounds: once per update, as once per ref epoch
    queries_per_round: int = 1  # ref: the one top-rated state of the epoch
    max_queries: Optional[int] = None  # total query budget; None: unlimited, as the ref
    buffer_size: int = 10_000  # visited states kept as negatives (24.6 kB each at 64 px, 2 cameras)
    seed: int = 0

    def to_dict(self) -> dict:
        """JSON-serialisable form (tuples as lists)."""
        return {k: (list(v) if isinstance(v, tuple) else v) for k, v in dataclasses.asdict(self).items()}

    @classmethod
    def from_dict(cls, d: dict) -> "VICEConfig":
        """Inverse of ``to_dict``."""
        d = dict(d)
        for k in ("cameras", "channels"):
            if k in d:
                d[k] = tuple(d[k])
        return cls(**d)


# ---------------------------------------------------------------------------- images
def preprocess(images: dict, cameras: Sequence[str], size: int) -> torch.Tensor:
    """Camera images ``{uid: uint8 [B, H, W, 3]}`` -> uint8 ``[B, 3 * len(cameras), size, size]``."""
    out = []
    for uid in cameras:
        if uid not in images:
            raise KeyError(f"no image from camera {uid!r}; have {sorted(images)}")
        x = torch.as_tensor(images[uid])
        if x.ndim == 3:
            x = x[None]
        x = x[..., :3].permute(0, 3, 1, 2).float()
        if x.shape[-1] != size or x.shape[-2] != size:
            # Area averaging: the shrink keeps thin edges (the socket rim) instead of aliasing them.
            x = F.interpolate(x, size=(size, size), mode="area")
        out.append(x.round().clamp(0, 255).to(torch.uint8))
    return torch.cat(out, dim=1)


class VICEClassifier(nn.Module):
    """Success classifier: a conv trunk per camera, concatenated features, an MLP to one logit."""

    def __init__(self, config: Optional[VICEConfig] = None):
        super().__init__()
        self.config = config = config or VICEConfig()
        self.trunks = nn.ModuleList()
        for _ in config.cameras:
            layers, c = [], 3
            for width in config.channels:
                layers += [nn.Conv2d(c, width, 3, stride=2, padding=1), nn.ReLU()]
                c = width
            layers += [nn.Flatten()]
            side = config.image_size
            for _ in config.channels:
                side = (side + 1) // 2
            layers += [nn.Linear(c * side * side, config.feature_dim), nn.ReLU()]
            self.trunks.append(nn.Sequential(*layers))
        self.head = nn.Sequential(
            nn.Linear(config.feature_dim * len(config.cameras), config.hidden_dim), nn.ReLU(),
            nn.Linear(config.hidden_dim, config.hidden_dim), nn.ReLU(),
            nn.Linear(config.hidden_dim, 1),
        )

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """Logits ``[B]`` of ``[B, 3 * cameras, S, S]`` images (uint8 0-255 or float in [0, 1])."""
        if x.dtype == torch.uint8:
            x = x.float() / 255.0
        feats = [trunk(x[:, 3 * i : 3 * i + 3]) for i, trunk in enumerate(self.trunks)]
        return self.head(torch.cat(feats, dim=1))[:, 0]

    @torch.no_grad()
    def log_prob(self, x: torch.Tensor, chunk: int = 512) -> torch.Tensor:
        """``log p(success | s)`` ``[B]``, in chunks, without gradients."""
        if len(x) == 0:
            return torch.zeros(0, device=x.device)
        return torch.cat([F.logsigmoid(self(x[i : i + chunk])) for i in range(0, len(x), chunk)])


# ---------------------------------------------------------------------------- goal examples
def goal_examples_from_h5(h5_path: str, cameras: Sequence[str] = VICEConfig.cameras) -> dict:
    """The last observation of every episode of a ManiSkill ``RecordEpisode`` .h5 (obs_mode rgb)."""
    import h5py

    found = {uid: [] for uid in cameras}
    with h5py.File(h5_path, "r") as f:
        for key in sorted(k for k in f.keys() if k.startswith("traj_")):
            for uid in cameras:
                path = f"{key}/obs/sensor_data/{uid}/rgb"
                if path not in f:
                    raise ValueError(f"{h5_path}: {path} missing; record the expert with obs_mode='rgb'")
                found[uid].append(torch.as_tensor(f[path][-1]))
    if not found[cameras[0]]:
        raise ValueError(f"{h5_path} holds no episodes")
    return {uid: torch.stack(v) for uid, v in found.items()}


# ---------------------------------------------------------------------------- the wrappers
def images_of(env: gym.Env, obs, config: VICEConfig, device) -> torch.Tensor:
    """The classifier's input ``[B, 3 * cameras, S, S]`` uint8 for ``env``'s current state."""
    return preprocess(camera_images(env, obs, config.cameras), config.cameras, config.image_size).to(device)


class SharedVICEReward(gym.Wrapper):
    """Reward an env with the classifier of a training ``VICERewardWrapper`` (for evaluation; stores nothing)."""

    def __init__(self, env: gym.Env, vice: "VICERewardWrapper"):
        super().__init__(env)
        self.vice = vice

    def step(self, action):
        """Step; reward = the shared classifier's ``log p(success | s')``, original in ``info["original_reward"]``."""
        obs, reward, terminated, truncated, info = self.env.step(action)
        info["original_reward"] = reward
        x = images_of(self.env, obs, self.vice.config, self.vice.device)
        return obs, self.vice.classifier.log_prob(x).to(reward.device), terminated, truncated, info


class VICERewardWrapper(gym.Wrapper):
    """Replace a ManiSkill env's reward with VICE-RAQ's ``log p(success | s)``; see the module docstring."""

    def __init__(self, env: gym.Env, goal_examples, config: Optional[VICEConfig] = None, device=None):
        super().__init__(env)
        self.config = config or VICEConfig()
        cfg = self.config
        self.device = torch.device(device or getattr(env.unwrapped, "device", "cpu"))
        with torch.random.fork_rng(devices=[]):
            # Seeded initial weights without moving the trainer's global torch RNG.
            torch.manual_seed(cfg.seed)
            self.classifier = VICEClassifier(cfg).to(self.device)
        self.optimizer = torch.optim.Adam(self.classifier.parameters(), lr=cfg.lr)
        self.rng = np.random.default_rng(cfg.seed)
        if isinstance(goal_examples, dict):
            goal_examples = preprocess(goal_examples, cfg.cameras, cfg.image_size)
        self.positives = torch.as_tensor(goal_examples).to(self.device, torch.uint8)
        self.num_goal_examples = len(self.positives)
        if self.num_goal_examples == 0:
            raise ValueError("VICE needs at least one goal example")
        c = 3 * len(cfg.cameras)
        self.buffer_images = torch.zeros(cfg.buffer_size, c, cfg.image_size, cfg.image_size, dtype=torch.uint8,
                                         device=self.device)
        self.buffer_success = torch.zeros(cfg.buffer_size, dtype=torch.bool, device=self.device)
        self.num_added = 0  # visited states ever added; the ring position is num_added % buffer_size
        self.query_mark = 0  # num_added at the last query round: candidates are the states since
        self.grad_steps = 0
        self.queries_used = 0
        self.queried_true = 0

    # ------------------------------------------------------------------ env side
    def _images(self, obs) -> torch.Tensor:
        return images_of(self.env, obs, self.config, self.device)

    def add_visited(self, images: torch.Tensor, success: torch.Tensor) -> None:
        """Store preprocessed visited states ``[B, C, S, S]`` and their success flags in the ring buffer."""
        n, cap = len(images), self.config.buffer_size
        idx = (self.num_added + torch.arange(n)) % cap
        self.buffer_images[idx.to(self.device)] = images.to(self.device)
        self.buffer_success[idx.to(self.device)] = torch.as_tensor(success, device=self.device).bool().reshape(n)
        self.num_added += n

    def step(self, action):
        """Step the env; reward = ``log p(success | s')`` ``[num_envs]``, original in ``info["original_reward"]``."""
        obs, reward, terminated, truncated, info = self.env.step(action)
        images = self._images(obs)
        self.add_visited(images, info["success"])
        info["original_reward"] = reward
        new_reward = self.classifier.log_prob(images)
        if isinstance(reward, torch.Tensor):
            new_reward = new_reward.to(reward.device)
        return obs, new_reward, terminated, truncated, info

    def evaluation_env(self, env: gym.Env) -> gym.Env:
        """``env`` rewarded by this wrapper's classifier, storing nothing (for evaluation episodes)."""
        return SharedVICEReward(env, self)

    # ------------------------------------------------------------------ learning side
    @property
    def update_every(self) -> int:
        """Env steps between classifier updates (``config.update_every``), for the trainer."""
        return self.config.update_every

    @property
    def num_visited(self) -> int:
        """Visited states currently in the buffer."""
        return min(self.num_added, self.config.buffer_size)

    def _batch(self):
        cfg = self.config
        b = cfg.batch_size
        pos = self.positives[torch.as_tensor(self.rng.integers(0, len(self.positives), b), device=self.device)]
        neg = self.buffer_images[torch.as_tensor(self.rng.integers(0, self.num_visited, b), device=self.device)]
        x = torch.cat([pos, neg]).float() / 255.0
        y = torch.cat([torch.ones(b), torch.zeros(b)]).to(self.device)
        if cfg.mixup_alpha > 0:
            # Mixup (ref): convex blends of pairs, images and labels alike, smooth the classifier
            # so its log-probability keeps a slope between the goal and the visited states.
            lam = torch.as_tensor(self.rng.beta(cfg.mixup_alpha, cfg.mixup_alpha, 2 * b), dtype=torch.float32,
                                  device=self.device)
            perm = torch.as_tensor(self.rng.permutation(2 * b), device=self.device)
            x = lam[:, None, None, None] * x + (1 - lam[:, None, None, None]) * x[perm]
            y = lam * y + (1 - lam) * y[perm]
        return x, y

    def active_query(self) -> dict:
        """Label the top-rated states visited since the last round by their success flag; true ones become positives."""
        cfg = self.config
        budget = cfg.queries_per_round
        if cfg.max_queries is not None:
            budget = min(budget, cfg.max_queries - self.queries_used)
        new = min(self.num_added - self.query_mark, cfg.buffer_size)
        self.query_mark = self.num_added
        if budget <= 0 or new <= 0:
            return dict(queried=0, added=0)
        idx = (self.num_added - new + torch.arange(new)) % cfg.buffer_size
        idx = idx.to(self.device)
        scores = self.classifier.log_prob(self.buffer_images[idx])
        top = idx[torch.topk(scores, min(budget, new)).indices]
        true = top[self.buffer_success[top]]
        if len(true):
            self.positives = torch.cat([self.positives, self.buffer_images[true].clone()])
        self.queries_used += len(top)
        self.queried_true += len(true)
        return dict(queried=len(top), added=len(true))

    def update(self, num_steps: Optional[int] = None) -> dict:
        """Train the classifier ``num_steps`` gradient steps (default ``config.train_steps``).

        Active queries run on their schedule; returns the metrics.
        """
        cfg = self.config
        num_steps = cfg.train_steps if num_steps is None else int(num_steps)
        metrics = dict(num_visited=self.num_visited)
        if self.num_visited == 0:
            # Nothing visited yet: no negatives to train on.
            metrics.update(steps=0, num_positives=len(self.positives), queries_used=self.queries_used)
            return metrics
        losses, added = [], 0
        self.classifier.train()
        for _ in range(num_steps):
            x, y = self._batch()
            loss = F.binary_cross_entropy_with_logits(self.classifier(x), y)
            self.optimizer.zero_grad(set_to_none=True)
            loss.backward()
            self.optimizer.step()
            losses.append(float(loss.detach()))
            self.grad_steps += 1
            if cfg.query_every > 0 and self.grad_steps % cfg.query_every == 0:
                added += self.active_query()["added"]
        metrics.update(
            steps=num_steps,
            loss=float(np.mean(losses)) if losses else float("nan"),
            loss_last=losses[-1] if losses else float("nan"),
            num_positives=len(self.positives),
            positives_added=added,
            queries_used=self.queries_used,
            queried_true=self.queried_true,
            grad_steps=self.grad_steps,
        )
        return metrics

    # ------------------------------------------------------------------ checkpoints
    def state_dict(self) -> dict:
        """Everything to resume: config, classifier, optimiser, positives, visited buffer, counters, RNG."""
        n = self.num_visited
        return dict(
            config=self.config.to_dict(),
            classifier=self.classifier.state_dict(),
            optimizer=self.optimizer.state_dict(),
            positives=self.positives.cpu(),
            num_goal_examples=self.num_goal_examples,
            # Only the filled part of the ring: a fresh run's checkpoint stays small.
            buffer_images=self.buffer_images[:n].cpu(),
            buffer_success=self.buffer_success[:n].cpu(),
            counters=dict(num_added=self.num_added, query_mark=self.query_mark, grad_steps=self.grad_steps,
                          queries_used=self.queries_used, queried_true=self.queried_true),
            rng=self.rng.bit_generator.state,
        )

    def load_state_dict(self, state: dict) -> None:
        """Restore a ``state_dict()``; the config must match in what shapes the model and buffer."""
        saved = VICEConfig.from_dict(state["config"])
        for key in ("cameras", "image_size", "channels", "feature_dim", "hidden_dim", "buffer_size"):
            if getattr(saved, key) != getattr(self.config, key):
                raise ValueError(f"VICE state has {key}={getattr(saved, key)!r}, "
                                 f"this wrapper {getattr(self.config, key)!r}")
        self.classifier.load_state_dict(state["classifier"])
        self.optimizer.load_state_dict(state["optimizer"])
        self.positives = state["positives"].to(self.device)
        self.num_goal_examples = int(state["num_goal_examples"])
        n = len(state["buffer_images"])
        self.buffer_images.zero_()
        self.buffer_success.zero_()
        self.buffer_images[:n] = state["buffer_images"].to(self.device)
        self.buffer_success[:n] = state["buffer_success"].to(self.device)
        for key, value in state["counters"].items():
            setattr(self, key, int(value))
        self.rng.bit_generator.state = state["rng"]
