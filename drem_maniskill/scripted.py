"""Where ``get_policy`` and its friends lived before 0.1's re-layering; they are now in ``drem_maniskill.experts``."""

from drem_maniskill.experts import (  # noqa: F401
    NOISY_EXPERT_SIGMA,
    POLICY_NAMES,
    STOCK_POLICY_NAMES,
    ee_control_kwargs,
    episode_horizon,
    get_policy,
    require_ee_control,
    success_rate,
)
