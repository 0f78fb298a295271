"""``compare``: success rate against env steps over seeds, one curve per reward, one panel per task (paper's Fig. 5)."""

from __future__ import annotations

import functools
import json
import textwrap
from collections import defaultdict
from pathlib import Path
from typing import Optional, Sequence

import numpy as np

from drem_maniskill.envs import is_insertion_task
from drem_maniskill.rl.config import drem_form_used, overlap_env_used
from drem_maniskill.rl.rewards import REWARDS, reward_checkpoint
from drem_maniskill.rl.train_policy import file_sha256, read_eval_csv


def steps_to_reach(steps: Sequence[float], values: Sequence[float], level: float = 0.5) -> Optional[float]:
    """First evaluated step at which ``values`` reaches ``level``, or None (no interpolation: what was measured)."""
    for s, v in zip(steps, values):
        if v >= level:
            return float(s)
    return None


def shipped_sha256(reward: str, task: str) -> Optional[str]:
    """sha256 of the checkpoint ``reward`` reads on ``task`` when given none (the shipped one), or None."""
    path = reward_checkpoint(reward, task) if reward in REWARDS else None
    if path is None or not path.exists():
        return None
    stat = path.stat()
    return _sha256_of(str(path), stat.st_mtime_ns, stat.st_size)


@functools.lru_cache(maxsize=None)
def _sha256_of(path: str, mtime_ns: int, size: int) -> str:
    # Every DREM run of a comparison asks for the same shipped file: hash it once per version of it.
    return file_sha256(path)


def _reached(step: Optional[float]):
    return "not reached" if step is None else round(step)


def run_label(cfg: dict, pinned: Optional[dict] = None) -> str:
    """The curve a run belongs to: its reward, and the settings that change what the reward teaches.

    ``pinned`` (the run's ``reward_checkpoint.json``) names the checkpoint by content: a run paid by
    the checkpoint shipped now joins the reward's curve whatever path it was given, and one paid by
    any other file is labelled with that file's sha256 (a retrained shipped file included).
    """
    label = cfg["reward"]
    if pinned is not None:
        if pinned["sha256"] != shipped_sha256(cfg["reward"], cfg["task"]):
            label += f" (checkpoint {pinned['sha256'][:8]})"
    elif cfg.get("reward_checkpoint"):
        label += f" ({cfg['reward_checkpoint']})"
    form = drem_form_used(cfg.get("drem_form"), bool(cfg.get("terminate_on_success")))
    reads_drem = cfg["reward"] in REWARDS and REWARDS[cfg["reward"]].checkpoint
    # Where episodes end at success the form matters either way (the paper's R is then a trap): always named.
    if reads_drem and (form != "paper" or cfg.get("terminate_on_success")):
        label += f", {form}"
    if cfg.get("terminate_on_success"):
        label += ", ends at success"
    normalised = _normalised_inputs(cfg)
    if normalised:
        label += ", norm " + "+".join(normalised)
    if cfg.get("action_scale", 1.0) != 1.0:
        label += f", actions x{cfg['action_scale']:g}"
    ratio = cfg.get("gradient_steps", 1) / cfg.get("train_freq", 1)
    if ratio != 1:
        label += f", updates x{ratio:g}"  # gradient steps per env step
    if cfg.get("train_bf16"):
        label += ", bf16"
    if overlap_env_used(bool(cfg.get("overlap_env")), cfg["reward"], cfg.get("algo", "sac")):
        label += ", overlapped"  # each action from the policy one update older
    return label


def _normalised_inputs(cfg: dict) -> list:
    """The policy inputs a run normalised: ``obs_norm`` less an F/T history its policy did not get (ManiSkill's own
    tasks have no F/T sensor)."""
    policy_ft = cfg.get("policy_ft", True)
    gets_ft = is_insertion_task(cfg["task"]) and (cfg["reward"] == "drem" if policy_ft is None else bool(policy_ft))
    return [k for k in cfg.get("obs_norm") or () if k != "ft" or gets_ft]


def load_run(run_dir) -> dict:
    """A run's config (task, reward label, seed) and its evaluation rows."""
    run_dir = Path(run_dir)
    cfg_path = run_dir / "config.json"
    if not cfg_path.exists():
        raise FileNotFoundError(f"{run_dir} is not a train-policy run dir (no config.json)")
    cfg = json.loads(cfg_path.read_text())
    rows = read_eval_csv(run_dir / "eval.csv")
    if not rows:
        raise ValueError(f"{run_dir}/eval.csv holds no evaluations yet")
    pin = run_dir / "reward_checkpoint.json"
    pinned = json.loads(pin.read_text()) if pin.exists() else None
    return dict(run_dir=str(run_dir), task=cfg["task"], reward=run_label(cfg, pinned), seed=cfg.get("seed"), rows=rows)


def shared_settings(labels: Sequence[str]) -> list:
    """The settings (``run_label``'s comma-separated parts after the reward) that every label of a panel has."""
    parts = [label.split(", ")[1:] for label in labels]
    return [p for p in parts[0] if all(p in other for other in parts[1:])] if parts else []


def aggregate(runs: list[dict]) -> dict:
    """Per (task, reward label): the seeds' curves on their common evaluation steps; mean, min, max, std."""
    groups = defaultdict(list)
    for run in runs:
        groups[(run["task"], run["reward"])].append(run)
    out = {}
    for key, group in groups.items():
        # Seeds may stop at different steps (a run still going): keep the steps all of them reached.
        common = sorted(set.intersection(*[{r["steps"] for r in run["rows"]} for run in group]))
        curves = np.array([[{r["steps"]: r["success_rate"] for r in run["rows"]}[s] for s in common] for run in group])
        mean = curves.mean(axis=0)
        out[key] = dict(steps=common, mean=mean, min=curves.min(axis=0), max=curves.max(axis=0), std=curves.std(axis=0),
                        curves=curves,
                        seeds=[run["seed"] for run in group], run_dirs=[run["run_dir"] for run in group])
    return out


def curve_row(task: str, reward: str, curve: dict, levels: Sequence[float]) -> dict:
    """The table row of one curve of ``aggregate``: final success, and the steps to each level (mean, per seed)."""
    row = dict(task=task, reward=reward, seeds=len(curve["seeds"]), final_steps=int(curve["steps"][-1]),
               final_success=float(curve["mean"][-1]), final_success_min=float(curve["min"][-1]),
               final_success_max=float(curve["max"][-1]), seed_ids=curve["seeds"])
    for level in levels:
        name = f"_to_{round(level * 100)}"
        row["steps" + name] = _reached(steps_to_reach(curve["steps"], list(curve["mean"]), level))
        row["seed_steps" + name] = [_reached(steps_to_reach(curve["steps"], list(c), level)) for c in curve["curves"]]
    return row


def markdown_table(table: list[dict], levels: Sequence[float]) -> str:
    """``curve_row`` rows as a Markdown table (the text of ``comparison.md``)."""
    names = [f"_to_{round(level * 100)}" for level in levels]
    head = ["task", "reward", "seeds", "final_steps", "final_success"] + [f"steps{n} (mean; per seed)" for n in names]
    lines = ["| " + " | ".join(head) + " |", "|" + " --- |" * len(head)]
    for r in table:
        final = f"{r['final_success']:.2f} ({r['final_success_min']:.2f}-{r['final_success_max']:.2f})"
        reach = [f"{r['steps' + n]}; {' / '.join(map(str, r['seed_steps' + n]))}" for n in names]
        lines.append(f"| {r['task']} | {r['reward']} | {r['seeds']} | {r['final_steps']} | {final} | "
                     + " | ".join(reach) + " |")
    return "\n".join(lines) + "\n"


def compare_runs(run_dirs: Sequence, out: str = "outputs/rl/compare", band: str = "minmax",
                 levels: Sequence[float] = (0.5, 0.8)) -> dict:
    """Plot and tabulate runs: ``<out>/comparison.png``, ``comparison.json``, ``comparison.md``; returns the table.

    Per curve: the final success and, per level, the steps at which the seeds' mean first reached it
    (``steps_to_50``, ``steps_to_80``) and at which each seed did (``seed_steps_to_80``, in ``seeds`` order).
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    if band not in ("minmax", "std"):
        raise ValueError(f"band must be 'minmax' or 'std', got {band!r}")
    runs = [load_run(d) for d in run_dirs]
    groups = aggregate(runs)
    tasks = sorted({t for t, _ in groups})
    out_dir = Path(out)
    out_dir.mkdir(parents=True, exist_ok=True)

    most = max(sum(t == task for t, _ in groups) for task in tasks)
    fig, axes = plt.subplots(1, len(tasks), figsize=(5.5 * len(tasks), 4 + 0.3 * most), squeeze=False)
    table = []
    for ax, task in zip(axes[0], tasks):
        shared = shared_settings([reward for t, reward in groups if t == task])
        for (t, reward), g in sorted(groups.items()):
            if t != task:
                continue
            x = np.asarray(g["steps"])
            lo, hi = (g["min"], g["max"]) if band == "minmax" else (g["mean"] - g["std"], g["mean"] + g["std"])
            own = ", ".join(part for part in reward.split(", ") if part not in shared)
            line, = ax.plot(x, g["mean"], label=textwrap.fill(f"{own} ({len(g['seeds'])} seeds)", 60))
            ax.fill_between(x, np.clip(lo, 0, 1), np.clip(hi, 0, 1), color=line.get_color(), alpha=0.2)
            table.append(curve_row(task, reward, g, levels))
        ax.set_title(task + ("\n" + textwrap.fill(", ".join(shared), 70) if shared else ""), fontsize=9)
        ax.set_xlabel("environment steps")
        ax.set_ylabel("success rate")
        ax.set_ylim(-0.02, 1.02)
        ax.grid(alpha=0.3)
        # Below the axes: long labels (checkpoint paths) would cover the curves.
        ax.legend(fontsize=7, loc="upper center", bbox_to_anchor=(0.5, -0.16), frameon=False)
    fig.suptitle(f"SAC success rate, mean and {'min-max' if band == 'minmax' else '±1 std'} over seeds")
    fig.tight_layout()
    png = out_dir / "comparison.png"
    fig.savefig(png, dpi=120)
    plt.close(fig)

    summary = dict(levels=list(levels), band=band, rows=table)
    (out_dir / "comparison.json").write_text(json.dumps(summary, indent=2) + "\n")
    (out_dir / "comparison.md").write_text(markdown_table(table, levels))
    return dict(png=str(png), json=str(out_dir / "comparison.json"), markdown=str(out_dir / "comparison.md"),
                rows=table)

