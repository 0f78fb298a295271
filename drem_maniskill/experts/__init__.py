"""Scripted policies (ours and ManiSkill's stock tasks), the one rollout loop, and demo recording.

``get_policy(name, env, seed)`` gives a batched policy; ``rollout(env, policy, seed)`` runs one
episode; ``record_expert`` writes episodes in ManiSkill's ``RecordEpisode`` format.
"""

from drem_maniskill.experts.control import ee_control_kwargs, require_ee_control
from drem_maniskill.experts.policies import NOISY_EXPERT_SIGMA, STOCK_POLICY_NAMES, get_policy
from drem_maniskill.experts.recording import RecordResult, record_expert
from drem_maniskill.experts.rollout import Episode, collect_goal_examples, rollout, success_rate
from drem_maniskill.experts.scripted import POLICY_NAMES
from drem_maniskill.utils.episodes import episode_horizon

__all__ = ["Episode", "NOISY_EXPERT_SIGMA", "POLICY_NAMES", "RecordResult", "STOCK_POLICY_NAMES",
           "collect_goal_examples", "ee_control_kwargs", "episode_horizon", "get_policy", "record_expert",
           "require_ee_control", "rollout",
           "success_rate"]
