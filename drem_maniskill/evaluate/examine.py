"""``examine``: judge a DREM reward by the rollouts of scripted policies; writes ``quality.json`` and the plot.

* **Value-order correlation**: mean Spearman correlation between the reward and the time step
  along expert episodes from held-out seeds (target >= 0.95).
* **Examination** (the paper's Fig. 4): reward against time for Direct Success, Align Success,
  Search Fail and Random; the AUROC of the final-step reward separating successful from failed
  episodes; the Random policy's mean reward (target <= 0.1); the reward just before and just
  after Search Fail loses contact.
* **The plateau, the drop, the colours** (our tasks): Align Success's reward on the face as a
  fraction of Direct Success's final one; Search Fail's reward 1 and 3 steps after it first
  loses contact; the reward at the probes (``probes.PROBES``) in every episode's colours, and its
  spread over the episodes.
* **The scene swap** at every successful expert end (``scene_swap``).

docs/drem.md, "Examination", defines each; ``quality`` assembles them, ``targets`` says what each should reach.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Sequence

import gymnasium as gym

from drem_maniskill.drem.wrapper import DREMRewardWrapper
from drem_maniskill.envs import is_insertion_task
from drem_maniskill.evaluate.plot import plot_examination
from drem_maniskill.evaluate.probes import hold_positions, hold_targets, hold_turns, hold_vias
from drem_maniskill.evaluate.quality import quality
from drem_maniskill.evaluate.scene_swap import scene_swap
from drem_maniskill.experts import ee_control_kwargs, get_policy, rollout
from drem_maniskill.experts.stock import STOCK_EXPERTS
from drem_maniskill.utils.atomic import write_text
from drem_maniskill.utils.progress import progress_bar

EXAMINATION = ("direct_success", "align_success", "search_fail", "random")
STOCK_EXAMINATION = ("direct_success", "noisy_expert", "random")


def _measure(env, obs, action, info) -> dict:
    """Per step beside the reward: the task's normalized_dense, insertion depth and wrist force where it has them."""
    u = env.unwrapped
    out = {}
    # The task's own shaped reward, for the correlation with DREM (every ManiSkill task with a
    # dense reward has it; PlugCharger-v1 does not).
    try:
        out["normalized_dense"] = float(u.compute_normalized_dense_reward(obs=obs, action=action, info=info)[0])
    except NotImplementedError:
        pass
    if "insertion_depth" in info:
        out["insertion_depth"] = float(info["insertion_depth"][0])
    if "radial_offset" in info:
        out["radial_offset"] = float(info["radial_offset"][0])
    if hasattr(u, "ft"):
        out["force"] = float(u.ft.buffer[0, -1, 2].abs())
    return out


def examination_episode(env, policy_name: str, seed: int, stop_on_success: bool = True) -> dict:
    """One episode: per-step reward, success, normalized_dense, insertion depth, radial offset and wrist force."""
    ep = rollout(env, get_policy(policy_name, env, seed=seed), seed, stop_on_success=stop_on_success, measure=_measure)
    measures = {k: ep.measures.get(k, []) for k in ("force", "normalized_dense", "insertion_depth", "radial_offset")}
    return dict(rewards=ep.rewards, success=ep.success, **measures)


def _make_env(env_id: str, checkpoint: str, env_kwargs: dict | None):
    """Our task with ``reward_mode="drem"``, or a stock task wrapped by ``DREMRewardWrapper``."""
    if is_insertion_task(env_id):
        return gym.make(
            env_id, obs_mode="state_dict", reward_mode="drem", drem_checkpoint=str(checkpoint), **(env_kwargs or {})
        )
    env = gym.make(env_id, obs_mode="state_dict", **ee_control_kwargs(env_id, env_kwargs))
    return DREMRewardWrapper(env, checkpoint)


def examine(env_id: str, checkpoint: str, seeds: Sequence[int] = range(20), out_dir: str | None = None,
            policies: Sequence[str] = EXAMINATION, env_kwargs: dict | None = None) -> dict:
    """Run the quality measures of the model card; writes ``quality.json`` and ``examination.png``.

    On ManiSkill's own tasks the examination policies are ``STOCK_EXAMINATION`` (direct_success
    is the stock expert there). The value-order correlation is over the expert's successful episodes.
    """
    if not is_insertion_task(env_id):
        allowed = STOCK_EXAMINATION if env_id in STOCK_EXPERTS else ("random",)
        policies = [p for p in (STOCK_EXAMINATION if tuple(policies) == EXAMINATION else policies) if p in allowed]
    env = _make_env(env_id, checkpoint, env_kwargs)
    try:
        expert, swaps = [], []
        for s in progress_bar(seeds, desc="examine: expert", unit="episode"):
            expert.append(examination_episode(env, "expert", s))
            if expert[-1]["success"]:
                swaps.append(scene_swap(env, s))
        curves = {p: [examination_episode(env, p, s, stop_on_success=False)
                      for s in progress_bar(seeds, desc=f"examine: {p}", unit="episode")]
                  for p in policies}
        held = {}
        if is_insertion_task(env_id):
            held = hold_positions(env, seeds, hold_targets(env), vias=hold_vias(env), turns=hold_turns(env))
    finally:
        env.close()
    result = quality(env_id, checkpoint, seeds, expert, curves, held, swaps)
    if out_dir:
        out = Path(out_dir)
        out.mkdir(parents=True, exist_ok=True)
        plot_examination(result, out / "examination.png")
        write_text(out / "quality.json", json.dumps(result, indent=1))
    return result
