"""``python -m drem_maniskill.experts [ENV_ID] [N_SEEDS] [HORIZON]``: the stock experts' success rates."""

import sys

from drem_maniskill.experts.rollout import success_rate
from drem_maniskill.experts.stock import STOCK_EXPERTS

ids = [sys.argv[1]] if len(sys.argv) > 1 else list(STOCK_EXPERTS)
n_seeds = int(sys.argv[2]) if len(sys.argv) > 2 else 50
horizon = {"max_episode_steps": int(sys.argv[3])} if len(sys.argv) > 3 else None
for env_id in ids:
    print(success_rate(env_id, "expert", range(n_seeds), env_kwargs=horizon))
