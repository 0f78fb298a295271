"""Baseline rewards of the paper's policy-learning comparison (Section IV-D).

* ``engineered``: ``-exp(kappa * ||x - x_G||)``, a reward mode of our tasks:
  ``gym.make("PegInHole-v1", reward_mode="engineered", engineered_kappa=10.0)``.
* ``vice``: VICE-RAQ, a learned success classifier on the camera images, as a wrapper:
  ``VICERewardWrapper(env, collect_goal_examples("PegInHole-v1", seeds=range(10)))``.

``sparse`` (the task's success flag) and ``drem`` are reward modes of the tasks themselves.
See docs/baselines.md.
"""

from drem_maniskill.baselines.engineered import DEFAULT_KAPPA, ROT_WEIGHT, engineered_reward, pose_distance
from drem_maniskill.baselines.vice import (
    VICEClassifier,
    VICEConfig,
    VICERewardWrapper,
    collect_goal_examples,
    goal_examples_from_h5,
)

# Names a trainer can offer for "the reward"; all but "vice" are env reward modes.
BASELINE_REWARDS = ("sparse", "engineered", "vice")

__all__ = [
    "BASELINE_REWARDS", "DEFAULT_KAPPA", "ROT_WEIGHT", "engineered_reward", "pose_distance",
    "VICEClassifier", "VICEConfig", "VICERewardWrapper", "collect_goal_examples", "goal_examples_from_h5",
]
