"""Baseline rewards of the paper's policy-learning comparison (Section IV-D).

* ``engineered``: ``-exp(kappa * ||x - x_G||)``, a reward mode of our tasks:
  ``gym.make("PegInHole-v1", reward_mode="engineered", engineered_kappa=10.0)``.
* ``vice``: VICE-RAQ, a learned success classifier on the camera images, as a wrapper:
  ``VICERewardWrapper(env, collect_goal_examples("PegInHole-v1", seeds=range(10)))``
  (``collect_goal_examples`` runs the scripted expert: ``drem_maniskill.experts``).

``sparse`` (the task's success flag) and ``drem`` are reward modes of the tasks themselves. The
names a trainer offers are the table ``drem_maniskill.rl.rewards.REWARDS``. See docs/baselines.md.
"""

from drem_maniskill.baselines.engineered import DEFAULT_KAPPA, ROT_WEIGHT, engineered_reward, pose_distance
from drem_maniskill.baselines.vice import (
    SharedVICEReward,
    VICEClassifier,
    VICEConfig,
    VICERewardWrapper,
    goal_examples_from_h5,
)

__all__ = [
    "DEFAULT_KAPPA", "ROT_WEIGHT", "engineered_reward", "pose_distance",
    "SharedVICEReward", "VICEClassifier", "VICEConfig", "VICERewardWrapper", "goal_examples_from_h5",
]
