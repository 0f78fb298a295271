"""The shipped checkpoints still pay what their committed examinations recorded (rewards/<task>/quality*.json)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from drem_maniskill.evaluate.examine import _make_env, examination_episode

REWARDS = Path(__file__).resolve().parents[2] / "rewards"
SHIPPED = [("PegInHole-v1", "drem.pt", "quality.json"), ("PegInHole-v1", "drem_image.pt", "quality_image.json"),
           ("USBInsertion-v1", "drem.pt", "quality.json"), ("USBInsertion-v1", "drem_image.pt", "quality_image.json")]


@pytest.mark.slow
@pytest.mark.parametrize("task,checkpoint,quality", SHIPPED)
def test_a_shipped_reward_replays_its_committed_direct_success_curve(task, checkpoint, quality):
    """The examination's first episode, re-run in a fresh env: the same 50 rewards as committed, step by step.

    Only the first episode of a fresh env replays exactly: PhysX carries contact caches from one episode to the next,
    so later episodes depend on the order the examination ran them in.
    """
    committed = json.loads((REWARDS / task / quality).read_text())
    expected = np.asarray(committed["curves"]["direct_success"][0])
    env = _make_env(task, str(REWARDS / task / checkpoint), None)
    try:
        episode = examination_episode(env, "direct_success", committed["seeds"][0], stop_on_success=False)
    finally:
        env.close()
    got = np.asarray(episode["rewards"])
    assert got.shape == expected.shape
    np.testing.assert_allclose(got, expected, atol=5e-3)
    assert got[-1] > 0.9  # and the curve is one a policy can learn from: it ends at the goal's reward
