"""``get_policy(name, env)``: a scripted policy by name, on our tasks and on ManiSkill's own.

On our insertion tasks: ``expert``, ``direct_success``, ``align_success``, ``search_fail``,
``random`` (``experts.scripted``). On ManiSkill's own tasks: ``random`` everywhere, and
``expert``, ``direct_success`` and ``noisy_expert`` where a stock expert exists
(``experts.stock``: PegInsertionSide-v1, PlugCharger-v1, PushCube-v1, StackCube-v1).
"""

from __future__ import annotations

from typing import Callable

import torch

from drem_maniskill.envs import InsertionEnv
from drem_maniskill.experts.scripted import POLICIES, POLICY_NAMES
from drem_maniskill.experts.stock import STOCK_EXPERTS, get_stock_expert
from drem_maniskill.experts.stock_base import NOISY_EXPERT_SIGMA  # noqa: F401  (re-exported)

# On ManiSkill's own tasks with a stock expert; noisy_expert adds N(0, sigma) to its normalised arm
# actions, sigma the expert's ``noisy_sigma``: 0.1 solves 30-50 % of PegInsertionSide-v1's and
# StackCube-v1's seeds (the examination's mix of successes and failures) and none of PlugCharger-v1's
# (0.5 mm clearance); PushCube-v1's expert takes 0.3 (about half), as 0.1 never fails there.
STOCK_POLICY_NAMES = ("expert", "direct_success", "noisy_expert", "random")


def get_policy(name: str, env, seed: int = 0) -> Callable:
    """A batched scripted policy ``policy(obs) -> action [num_envs, action_dim]`` for ``env``.

    On ManiSkill's own tasks ``random`` (uniform random actions) exists everywhere, and ``expert`` and
    ``noisy_expert`` on PegInsertionSide-v1, PlugCharger-v1, PushCube-v1 and StackCube-v1
    (``drem_maniskill.experts.stock``, ``pd_ee_delta_pose``).
    """
    if not isinstance(env.unwrapped, InsertionEnv):
        if name == "random":
            return UniformRandom(env, seed)
        if name in ("expert", "direct_success", "noisy_expert"):
            if env.unwrapped.spec.id in STOCK_EXPERTS:
                noise = STOCK_EXPERTS[env.unwrapped.spec.id].noisy_sigma if name == "noisy_expert" else 0.0
                return get_stock_expert(env, seed=seed, action_noise=noise)
            raise ValueError(
                f"no scripted expert for {env.unwrapped.spec.id} "
                f"(experts ship for our tasks and {sorted(STOCK_EXPERTS)}); "
                "record your own demo with ManiSkill's RecordEpisode (obs_mode='rgb', record_env_state=True) "
                "and pass it to `drem-maniskill sample`"
            )
        raise ValueError(f"scripted policy {name!r} exists only for our insertion tasks; on {env.unwrapped.spec.id} "
                         f"choose one of {list(STOCK_POLICY_NAMES)}")
    if name not in POLICIES:
        raise ValueError(f"unknown scripted policy {name!r}; choose one of {list(POLICY_NAMES)}")
    policy = POLICIES[name](env, seed=seed)
    policy._on_reset(torch.ones(policy.n, dtype=torch.bool, device=policy.device))
    return policy


class UniformRandom:
    """Uniform random actions in the env's (normalised) action space, seeded."""

    def __init__(self, env, seed: int = 0):
        space = env.unwrapped.single_action_space
        self.low = torch.as_tensor(space.low, dtype=torch.float32)
        self.high = torch.as_tensor(space.high, dtype=torch.float32)
        self.n, self.device = env.unwrapped.num_envs, env.unwrapped.device
        self.generator = torch.Generator().manual_seed(int(seed))

    def __call__(self, obs) -> torch.Tensor:
        """Actions ``[num_envs, action_dim]``."""
        u = torch.rand(self.n, len(self.low), generator=self.generator)
        return (self.low + u * (self.high - self.low)).to(self.device)
