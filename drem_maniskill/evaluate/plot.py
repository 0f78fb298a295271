"""The examination's plot (the paper's Fig. 4): reward against time per examination policy, and the probes held."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from drem_maniskill.utils.atomic import atomic_path


def _held_panel(ax, held: dict, result: dict) -> None:
    """The reward with the tip held at each probe: mean and spread over episodes (colours randomised)."""
    x = np.arange(len(held))
    ax.bar(x, [v["mean"] for v in held.values()], yerr=[v["std"] for v in held.values()], capsize=3, color="C7")
    ax.set_xticks(x, list(held), rotation=40, ha="right", fontsize=7)
    ax.set_ylabel("DREM reward, tip held (mean, std over episodes)")
    spread = result.get("colour_spread", {}).get("max_std")
    ax.set_title(f"colour spread: largest std {spread:.3f}" if spread is not None else "held positions")


def _curves_panel(ax, runs_by_policy: dict, success_rate: dict, ylabel: str) -> None:
    """Each policy's per-step values: the mean over its episodes, and one standard deviation either side."""
    for i, (name, runs) in enumerate(runs_by_policy.items()):
        length = max(len(r) for r in runs)
        arr = np.full((len(runs), length), np.nan)
        for k, r in enumerate(runs):
            arr[k, : len(r)] = r
        mean, std = np.nanmean(arr, 0), np.nanstd(arr, 0)
        t = np.arange(1, length + 1)
        ax.plot(t, mean, color=f"C{i}", label=f"{name} (success {success_rate[name]:.0%})")
        ax.fill_between(t, mean - std, mean + std, color=f"C{i}", alpha=0.2)
    ax.set_xlabel("time step")
    ax.set_ylabel(ylabel)
    ax.legend(fontsize=8)


def plot_examination(result: dict, path: Path) -> None:
    """Reward against time step per policy, mean and spread over seeds (the paper's Fig. 4)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    # Beside DREM, the task's own normalized_dense where it has one (ManiSkill's stock tasks).
    dense = {k: v for k, v in result.get("dense_curves", {}).items() if any(len(r) for r in v)}
    panels = [("curves", "DREM reward")] + ([("dense_curves", "ManiSkill normalized_dense")] if dense else [])
    held = {k: v for k, v in result.get("held_positions", {}).items() if v["mean"] is not None}
    fig, axes = plt.subplots(1, len(panels) + bool(held), figsize=(7 * (len(panels) + bool(held)), 5.5), squeeze=False)
    if held:
        _held_panel(axes[0, -1], held, result)
    for ax, (key, ylabel) in zip(axes[0], panels):
        _curves_panel(ax, result[key], result["success_rate"], ylabel)
    axes[0, 0].set_title(f"{result['env_id']}: value-order Spearman {result['value_order_spearman']:.2f}, "
                         f"AUROC {result['final_reward_auroc']:.2f}")
    if dense and result.get("spearman_with_normalized_dense") is not None:
        axes[0, 1].set_title(f"Spearman(DREM, normalized_dense) = {result['spearman_with_normalized_dense']:.2f}")
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=90, format=Path(path).suffix.lstrip(".") or "png")
    plt.close(fig)
