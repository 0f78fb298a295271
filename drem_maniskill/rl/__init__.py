"""SAC policy learning with DREM and the baseline rewards (the paper's Section IV-D); see docs/rl.md.

* ``train_policy(RLConfig.from_preset("light", task=..., reward=..., seed=...))`` trains or resumes a run;
* ``REWARDS`` (``rl.rewards``) maps reward names to how their env is built, one entry per reward;
* ``ALGOS`` (``rl.algos``) maps algorithm names to how they are built, saved and loaded (SAC);
* ``compare_runs(run_dirs, out)`` draws success against env steps per task and reward.
"""

from drem_maniskill.rl.config import PRESETS, RLConfig
from drem_maniskill.rl.rewards import REWARDS, RewardSpec, reward_spec

__all__ = ["PRESETS", "RLConfig", "REWARDS", "RewardSpec", "reward_spec", "ALGOS", "train_policy", "compare_runs"]


def __getattr__(name):
    # stable-baselines3 and matplotlib load only when training or comparing.
    if name == "train_policy":
        from drem_maniskill.rl.train_policy import train_policy

        return train_policy
    if name == "ALGOS":
        from drem_maniskill.rl.algos import ALGOS

        return ALGOS
    if name == "compare_runs":
        from drem_maniskill.rl.compare import compare_runs

        return compare_runs
    raise AttributeError(name)
