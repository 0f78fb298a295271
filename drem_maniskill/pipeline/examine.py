"""Measure a DREM reward: value-order correlation, examination policies, plots.

* **Value-order correlation**: mean Spearman correlation between the reward and the time step
  along expert episodes from held-out seeds (target >= 0.9).
* **Examination** (the paper's Fig. 4): reward against time for Direct Success, Align Success,
  Search Fail and Random; the AUROC of the final-step reward separating successful from failed
  episodes; the Random policy's mean reward (target < 0.2); the reward just before and just
  after Search Fail loses contact.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Sequence

import gymnasium as gym
import numpy as np
from scipy.stats import spearmanr
from tqdm import tqdm

from drem_maniskill.drem.wrapper import DREMRewardWrapper
from drem_maniskill.envs import is_insertion_task
from drem_maniskill.experts import ee_control_kwargs, get_policy, rollout
from drem_maniskill.experts.stock import STOCK_EXPERTS

EXAMINATION = ("direct_success", "align_success", "search_fail", "random")
STOCK_EXAMINATION = ("direct_success", "noisy_expert", "random")


def auroc(scores_pos: Sequence[float], scores_neg: Sequence[float]) -> float:
    """Area under the ROC curve (Mann-Whitney U); NaN when a class is empty."""
    pos, neg = np.asarray(scores_pos, float), np.asarray(scores_neg, float)
    if len(pos) == 0 or len(neg) == 0:
        return float("nan")
    greater = (pos[:, None] > neg[None, :]).sum() + 0.5 * (pos[:, None] == neg[None, :]).sum()
    return float(greater / (len(pos) * len(neg)))


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
    if hasattr(u, "ft"):
        out["force"] = float(u.ft.buffer[0, -1, 2].abs())
    return out


def examination_episode(env, policy_name: str, seed: int, stop_on_success: bool = True) -> dict:
    """One episode: per-step reward, success, normalized_dense, insertion depth and wrist force."""
    ep = rollout(env, get_policy(policy_name, env, seed=seed), seed, stop_on_success=stop_on_success, measure=_measure)
    return dict(rewards=ep.rewards, success=ep.success, **{k: ep.measures.get(k, []) for k in ("force", "normalized_dense", "insertion_depth")})


def _pooled_spearman(episodes: list, key: str) -> float | None:
    """Spearman correlation of DREM reward with ``key`` over all steps of ``episodes``."""
    pairs = [(r, v) for ep in episodes if len(ep.get(key, [])) == len(ep["rewards"]) for r, v in zip(ep["rewards"], ep[key])]
    if len(pairs) < 3:
        return None
    a, b = np.array(pairs).T
    if np.ptp(a) == 0 or np.ptp(b) == 0:
        return None
    return float(spearmanr(a, b).correlation)


def _make_env(env_id: str, checkpoint: str, env_kwargs: dict | None):
    """Our task with ``reward_mode="drem"``, or a stock task wrapped by ``DREMRewardWrapper``."""
    if is_insertion_task(env_id):
        return gym.make(env_id, obs_mode="state_dict", reward_mode="drem", drem_checkpoint=str(checkpoint), **(env_kwargs or {}))
    return DREMRewardWrapper(gym.make(env_id, obs_mode="state_dict", **ee_control_kwargs(env_id, env_kwargs)), checkpoint)


def contact_loss_drop(episode: dict, contact: float = 3.0) -> tuple[float, float] | None:
    """Reward just before and just after the last fall of the wrist force below ``contact``."""
    f = np.asarray(episode["force"])
    for t in range(len(f) - 1, 0, -1):
        if f[t - 1] > contact and f[t] < 1.0:
            return episode["rewards"][t - 1], episode["rewards"][t]
    return None


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
        expert = [examination_episode(env, "expert", s) for s in tqdm(seeds, desc="examine: expert", unit="episode", disable=None)]
        curves = {p: [examination_episode(env, p, s, stop_on_success=False) for s in tqdm(seeds, desc=f"examine: {p}", unit="episode", disable=None)]
                  for p in policies}
    finally:
        env.close()
    solved = [e for e in expert if e["success"]]
    rho = [spearmanr(np.arange(len(e["rewards"])), e["rewards"]).correlation for e in solved if len(e["rewards"]) > 2]
    finals = [(ep["rewards"][-1], ep["success"]) for eps in curves.values() for ep in eps]
    drops = [d for ep in curves.get("search_fail", []) if (d := contact_loss_drop(ep)) is not None]
    result = dict(
        env_id=env_id, checkpoint=str(checkpoint), seeds=list(map(int, seeds)),
        value_order_spearman=float(np.nanmean(rho)) if rho else float("nan"),
        value_order_spearman_per_episode=[float(r) for r in rho],
        expert_success_rate=float(np.mean([e["success"] for e in expert])) if expert else float("nan"),
        final_reward_auroc=auroc([r for r, s in finals if s], [r for r, s in finals if not s]),
        random_mean_reward=float(np.mean([np.mean(ep["rewards"]) for ep in curves.get("random", [])])) if "random" in curves else None,
        search_fail_contact_loss=dict(
            episodes_with_loss=len(drops),
            before=float(np.mean([d[0] for d in drops])) if drops else None,
            after=float(np.mean([d[1] for d in drops])) if drops else None,
        ),
        success_rate={p: float(np.mean([ep["success"] for ep in eps])) for p, eps in curves.items()},
        # Over every step of the expert and examination rollouts.
        spearman_with_normalized_dense=_pooled_spearman(everything := expert + [ep for eps in curves.values() for ep in eps],
                                                        "normalized_dense"),
        spearman_with_insertion_depth=_pooled_spearman(everything, "insertion_depth"),
        spearman_with_normalized_dense_expert=_pooled_spearman(expert, "normalized_dense"),
        dense_curves={p: [ep["normalized_dense"] for ep in eps] for p, eps in curves.items()},
        curves={p: [ep["rewards"] for ep in eps] for p, eps in curves.items()},
        expert_curves=[e["rewards"] for e in expert],
    )
    if out_dir:
        out = Path(out_dir)
        out.mkdir(parents=True, exist_ok=True)
        plot_examination(result, out / "examination.png")
        tmp = out / ".quality.json.tmp"
        tmp.write_text(json.dumps(result, indent=1))
        os.replace(tmp, out / "quality.json")
    return result


def plot_examination(result: dict, path: Path) -> None:
    """Reward against time step per policy, mean and spread over seeds (the paper's Fig. 4)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    # Beside DREM, the task's own normalized_dense where it has one (ManiSkill's stock tasks).
    dense = {k: v for k, v in result.get("dense_curves", {}).items() if any(len(r) for r in v)}
    panels = [("curves", "DREM reward")] + ([("dense_curves", "ManiSkill normalized_dense")] if dense else [])
    fig, axes = plt.subplots(1, len(panels), figsize=(7 * len(panels), 4), squeeze=False)
    for ax, (key, ylabel) in zip(axes[0], panels):
        for i, (name, runs) in enumerate(result[key].items()):
            length = max(len(r) for r in runs)
            arr = np.full((len(runs), length), np.nan)
            for k, r in enumerate(runs):
                arr[k, : len(r)] = r
            mean, std = np.nanmean(arr, 0), np.nanstd(arr, 0)
            t = np.arange(1, length + 1)
            ax.plot(t, mean, color=f"C{i}", label=f"{name} (success {result['success_rate'][name]:.0%})")
            ax.fill_between(t, mean - std, mean + std, color=f"C{i}", alpha=0.2)
        ax.set_xlabel("time step")
        ax.set_ylabel(ylabel)
        ax.legend(fontsize=8)
    axes[0, 0].set_title(f"{result['env_id']}: value-order Spearman {result['value_order_spearman']:.2f}, "
                         f"AUROC {result['final_reward_auroc']:.2f}")
    if dense and result.get("spearman_with_normalized_dense") is not None:
        axes[0, 1].set_title(f"Spearman(DREM, normalized_dense) = {result['spearman_with_normalized_dense']:.2f}")
    fig.tight_layout()
    tmp = path.with_suffix(".tmp.png")
    fig.savefig(tmp, dpi=90)
    plt.close(fig)
    os.replace(tmp, path)
