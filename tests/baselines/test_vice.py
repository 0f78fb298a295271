"""VICE-RAQ: the success classifier, active queries, checkpoints, the wrapper on a task."""

from __future__ import annotations

import math

import gymnasium as gym
import numpy as np
import pytest
import torch

from drem_maniskill.baselines.vice import (
    VICEClassifier,
    VICEConfig,
    VICERewardWrapper,
    goal_examples_from_h5,
    preprocess,
)
from drem_maniskill.experts import collect_goal_examples, get_policy
from tests.conftest import TASKS, make_env

CAMS = ("fixed_camera", "wrist_camera")


class FakeCameraEnv(gym.Env):
    """Two 16 px "cameras": success states show a bright square, others dark noise. No physics."""

    def __init__(self, num_envs=2, success_rate=0.0, seed=0):
        self.num_envs, self.device = num_envs, torch.device("cpu")
        self.success_rate = success_rate
        self.gen = torch.Generator().manual_seed(seed)
        self.observation_space = gym.spaces.Box(0, 255, (1,))
        self.action_space = gym.spaces.Box(-1, 1, (2,))

    def frames(self, success: torch.Tensor) -> dict:
        """Images for a batch of success flags."""
        n = len(success)
        img = torch.randint(0, 60, (n, 16, 16, 3), generator=self.gen, dtype=torch.uint8)
        img[success, 4:12, 4:12] = 230
        return {uid: img.clone() for uid in CAMS}

    def _obs(self, success):
        return {"sensor_data": {uid: {"rgb": im} for uid, im in self.frames(success).items()}}

    def reset(self, seed=None, options=None):
        return self._obs(torch.zeros(self.num_envs, dtype=torch.bool)), {}

    def step(self, action):
        success = torch.rand(self.num_envs, generator=self.gen) < self.success_rate
        info = {"success": success}
        reward = success.float()
        done = torch.zeros(self.num_envs, dtype=torch.bool)
        return self._obs(success), reward, done, done, info


def tiny_config(**kw) -> VICEConfig:
    """A fast config for the synthetic tests."""
    base = dict(image_size=16, channels=(8, 8), feature_dim=16, hidden_dim=32, lr=1e-3, batch_size=32, buffer_size=64)
    base.update(kw)
    return VICEConfig(**base)


def test_vice_classifier_separates_goals_from_visited_states():
    env = FakeCameraEnv(num_envs=4)
    goals = env.frames(torch.ones(8, dtype=torch.bool))
    w = VICERewardWrapper(env, goals, tiny_config(query_every=0))
    w.reset()
    for _ in range(8):
        w.step(None)
    first = w.update(5)["loss"]
    for _ in range(6):
        last = w.update(10)["loss"]
    assert last < first * 0.7, (first, last)
    pos = w.classifier.log_prob(preprocess(env.frames(torch.ones(16, dtype=torch.bool)), CAMS, 16))
    neg = w.classifier.log_prob(preprocess(env.frames(torch.zeros(16, dtype=torch.bool)), CAMS, 16))
    assert float(pos.min()) > float(neg.max())
    assert float(pos.mean()) > math.log(0.5) > float(neg.mean())


def test_active_queries_add_only_true_successes_within_budget():
    env = FakeCameraEnv(num_envs=4, success_rate=0.0)
    goals = env.frames(torch.ones(4, dtype=torch.bool))
    w = VICERewardWrapper(env, goals, tiny_config(query_every=1, queries_per_round=2, max_queries=5))
    w.reset()
    for _ in range(4):
        w.step(None)
    # No state visited is a success: queries are spent, nothing joins the positives.
    m = w.update(1)
    assert m["queries_used"] == 2 and m["num_positives"] == 4 and m["positives_added"] == 0
    # Now visited states look like goals and are: the top-rated ones are true positives.
    env.success_rate = 1.0
    for _ in range(2):
        w.step(None)
    m = w.update(1)
    assert m["positives_added"] == 2 and m["num_positives"] == 6 and m["queries_used"] == 4
    # Budget: 5 in all; one left, then none, however many rounds run.
    for _ in range(3):
        w.step(None)
        m = w.update(1)
    assert m["queries_used"] == 5 and m["num_positives"] == 7 and w.queried_true == 3
    # A round without new visited states queries nothing.
    w2 = VICERewardWrapper(env, goals, tiny_config(query_every=1))
    assert w2.update(1)["steps"] == 0 and w2.queries_used == 0


def test_vice_state_dict_round_trip(tmp_path):
    env = FakeCameraEnv(num_envs=3, success_rate=0.5)
    goals = env.frames(torch.ones(4, dtype=torch.bool))
    w = VICERewardWrapper(env, goals, tiny_config(query_every=2))
    w.reset()
    for _ in range(30):  # more than the buffer holds: the ring wraps
        w.step(None)
    w.update(4)
    path = tmp_path / "vice.pt"
    torch.save(w.state_dict(), path)
    w2 = VICERewardWrapper(env, env.frames(torch.ones(1, dtype=torch.bool)), tiny_config(query_every=2))
    w2.load_state_dict(torch.load(path, weights_only=False))
    x = preprocess(env.frames(torch.tensor([True, False])), CAMS, 16)
    assert torch.equal(w.classifier.log_prob(x), w2.classifier.log_prob(x))
    assert torch.equal(w.positives, w2.positives) and torch.equal(w.buffer_images, w2.buffer_images)
    assert torch.equal(w.buffer_success, w2.buffer_success)
    counters = ("num_added", "query_mark", "grad_steps", "queries_used")
    assert [getattr(w, c) for c in counters] == [getattr(w2, c) for c in counters]
    # Resumed training continues exactly as the original would.
    assert w.update(3) == w2.update(3)
    assert torch.equal(w.classifier.log_prob(x), w2.classifier.log_prob(x))
    with pytest.raises(ValueError, match="image_size"):
        VICERewardWrapper(env, goals, tiny_config(image_size=32)).load_state_dict(w.state_dict())


def test_vice_wrapper_on_a_task():
    task = TASKS[0]
    env = make_env(task, obs_mode="rgb", reward_mode="dense")
    goals = collect_goal_examples(task, seeds=[0], env=env)
    assert goals["fixed_camera"].shape == (1, 128, 128, 3) and goals["fixed_camera"].dtype == torch.uint8
    cfg = VICEConfig(buffer_size=32, batch_size=8, query_every=2)
    w = VICERewardWrapper(env, goals, cfg)
    policy = get_policy("random", env)
    obs, _ = w.reset(seed=1)
    for _ in range(3):
        obs, reward, _, _, info = w.step(policy(obs))
        assert reward.shape == (env.unwrapped.num_envs,) and reward.dtype == torch.float32
        assert bool((reward <= 0).all())  # a log-probability
        assert "original_reward" in info and info["original_reward"].shape == reward.shape
    m = w.update(2)
    assert m["steps"] == 2 and np.isfinite(m["loss"]) and m["num_visited"] == 3 and m["queries_used"] == 1
    assert m["positives_added"] == 0  # a random policy from the start region never succeeds


def test_goal_examples_from_the_shipped_expert_demo():
    from pathlib import Path

    path = Path(__file__).resolve().parents[2] / "tasks" / TASKS[1] / "expert.h5"
    goals = goal_examples_from_h5(str(path))
    assert goals["wrist_camera"].shape[0] == 1 and goals["wrist_camera"].shape[-1] == 3
    x = preprocess(goals, CAMS, 64)
    assert x.shape == (1, 6, 64, 64) and x.dtype == torch.uint8
    assert VICEClassifier(VICEConfig())(x).shape == (1,)
