"""Policy rounds: hard negatives from the states a policy trained on the reward reaches (beyond the paper).

A DREM reward is taught by its progress tree, and a policy finds the states the tree lacks: where the
reward pays almost what it pays the goal and the task is not done. Each round closes that loop without
anyone naming the states:

1. SAC (the ``state`` preset) trains on the current reward for ``sac_steps``;
2. its policy runs ``episodes`` held-out episodes, sampling its actions; in every episode without success,
   the states the reward pays at least what it pays the tree's nodes at ``negative_depth`` (or, with
   ``trap_share``, that share of what it pays the goal) are hard negatives (the measured rule: paid more than a
   node that far from the goal, yet no success);
3. they join the tree at depth ``negative_depth``, farther from the goal than its neighbourhood
   (``2 eps + 1`` by default: beyond the goal's neighbours and theirs), or with ``trap_label = "start"`` at the
   depth of the start region, and the model is fine-tuned from the current weights for ``iterations`` on the tree
   and every round's negatives.

A policy also fails where the reward stops rising short of the goal: a plateau no trap rule sees, since it pays
less than the goal. With ``stall_window > 0`` a round looks for it too: a failed episode whose reward rose by less
than ``stall_rise`` over its last ``stall_window`` of steps stalled there, and those steps join the tree one
neighbourhood (``eps + 1``) farther from the goal than the nearest depth whose nodes the reward pays no more than it
pays the step. The reward thereby learns that where the policy waits is not as far along as the tree's states it
resembles, whatever the task.

Every round lives in ``<out>/round_<k>/`` (``sac/``, ``negatives.h5``: a ``pipeline.negatives`` file,
``train/drem.pt``) and a finished stage is never redone: a killed round, rerun, goes on from its last finished
stage (the SAC run and the training from their own checkpoints). The checkpoint's header lists the rounds
(``rounds``), the model card too.
"""

from __future__ import annotations

import dataclasses
import functools
import json
from dataclasses import dataclass
from pathlib import Path
from typing import Optional, Sequence

import numpy as np
import torch

from drem_maniskill.utils.checks import check_fraction

from drem_maniskill.pipeline.negatives import paid_on_negatives, write_negatives
from drem_maniskill.utils.atomic import write_json
from drem_maniskill.utils.episodes import max_episode_steps
from drem_maniskill.utils.progress import progress_bar


@dataclass
class RoundsConfig:
    """Policy rounds of ``build-reward`` (the recipe's ``[rounds]``); ``rounds = 0``: none, the paper's pipeline."""

    rounds: int = 0
    """Rounds of SAC, hard negatives and fine-tuning."""
    sac_steps: int = 10_000
    """SAC env steps per round (the state preset)."""
    learning_starts: int = 1_000
    """SAC's random steps before its first update."""
    episodes: int = 20
    """Episodes of the round's policy (sampled actions) searched for hard negatives."""
    negative_depth: Optional[int] = None
    """The depth hard negatives are labelled with; None: 2 eps + 1."""
    trap_label: str = "depth"
    """What the traps (the failed states a round finds paid like the goal) are labelled: ``depth``,
    ``negative_depth``; ``start``, the tree's start-region depth: a failed state paid like the goal is put as far from
    it as the start, since nothing in the tree says how far it is."""
    trap_share: Optional[float] = None
    """With a value in (0, 1], a failed state is a trap when paid at least this share of what the reward pays the
    tree's goal (depth 0), the rule ``check-reward`` judges a paid failure by (0.8); None: at least ``negative_depth``'s
    pay."""
    max_negatives: int = 1_000
    """At most this many hard negatives per round (evenly spread over the candidates)."""
    iterations: int = 1_000
    """Fine-tuning iterations per round, from the previous round's weights."""
    seed: int = 0
    """Seed of round 1's SAC run and episodes (round k: seed + k - 1)."""
    stall_window: float = 0.0
    """The share of a failed episode's last steps searched for a stall; 0: stalls are not looked for."""
    stall_rise: float = 0.02
    """A failed episode stalled when its best reward in the window exceeds its best before it by less than this."""

    def __post_init__(self):
        check_fraction("rounds.trap_share", self.trap_share, "the goal's pay", optional=True)
        if self.trap_label not in TRAP_LABELS:
            raise ValueError(f"rounds.trap_label = {self.trap_label!r} is not a label: use one of {list(TRAP_LABELS)}")

    def depth(self, eps: float) -> int:
        """The depth whose pay makes a failed state a trap, for the triplet loss's ``eps`` (``negative_depth``)."""
        return int(self.negative_depth) if self.negative_depth is not None else int(2 * eps + 1)

    def trap_depth(self, eps: float, start_depth: Optional[int]) -> int:
        """The depth label of a trap in a tree whose backward loop reached the start region at ``start_depth``."""
        if self.trap_label != "start":
            return self.depth(eps)
        if start_depth is None:
            raise ValueError("rounds.trap_label = 'start' labels traps at the tree's start-region depth, but this tree "
                             "never reached the start region: sample it further, or use trap_label = 'depth'")
        return int(start_depth)


TRAP_LABELS = ("depth", "start")


def round_policy_config(task: str, checkpoint, config: RoundsConfig, k: int, round_dir: Path):
    """The SAC run of round ``k``: the state preset on the drem reward paid by ``checkpoint``."""
    from drem_maniskill.rl.config import RLConfig

    return RLConfig.from_preset("state", task=task, reward="drem", seed=config.seed + k - 1, steps=config.sac_steps,
                                learning_starts=config.learning_starts, eval_every=config.sac_steps, eval_episodes=3,
                                reward_checkpoint=str(checkpoint), out=str(round_dir / "sac"))


def tree_pay(checkpoint, tree: str) -> tuple:
    """``(reward, tree)``: the ``DREMReward`` of ``checkpoint`` and the tree as its model reads it, loaded once for
    ``paid_at_depth`` and ``paid_by_depth``."""
    from drem_maniskill.drem.reward import DREMReward
    from drem_maniskill.pipeline.dataset import TreeDataset

    reward = DREMReward.from_checkpoint(str(checkpoint))
    return reward, TreeDataset(tree, reward.model.config)


@torch.no_grad()
def _mean_paid(reward, data, idx) -> float:
    """The mean ``R`` ``reward`` pays the tree's nodes ``idx``."""
    batch = data.batch(idx)
    if not reward.uses_ft:
        batch.pop("ft")
    return float(reward(batch).mean())


def paid_at_depth(reward, data, depth: int) -> float:
    """The mean ``R`` the reward pays the tree's nodes at ``depth`` (the nearest depth the tree has; ``tree_pay``)."""
    nearest = min(data.by_depth, key=lambda d: abs(d - depth))
    return _mean_paid(reward, data, data.by_depth[nearest][:256])


def trap_threshold(reward, data, config: RoundsConfig, depth: int) -> float:
    """The least pay that makes a failed state a trap: ``trap_share`` of the goal's pay, else ``depth``'s pay."""
    if config.trap_share is None:
        return paid_at_depth(reward, data, depth)
    return config.trap_share * paid_at_depth(reward, data, 0)


def paid_by_depth(reward, data, per_depth: int = 64) -> tuple:
    """What the reward pays the tree's nodes, by depth: ``(depths, mean R)``, depths ascending (the goal first)."""
    depths = np.array(sorted(data.by_depth))
    return depths, np.array([_mean_paid(reward, data, data.by_depth[int(d)][:per_depth]) for d in depths])


def stall_depth(paid: float, depths: np.ndarray, paid_curve: np.ndarray, eps: float) -> int:
    """The label of a stalled state paid ``paid``: ``eps + 1`` beyond the nearest depth paid no more than it."""
    below = depths[paid_curve <= paid]
    return int((below.min() if len(below) else depths.max()) + int(eps) + 1)


def stalled_steps(paid: Sequence[float], window: float, rise: float) -> range:
    """The steps where an episode paid ``paid`` stalled: its last ``window`` share, or none where it still rose."""
    n = max(1, int(round(window * len(paid))))
    if n >= len(paid):
        return range(0)
    before, last = max(paid[:-n]), max(paid[-n:])
    return range(len(paid) - n, len(paid)) if last - before < rise else range(0)


def collect_negatives(run, checkpoint, threshold: float, config: RoundsConfig, k: int, depth: int,
                      stall_label=None) -> dict:
    """Run round ``k``'s policy (sampled actions) and keep the failed episodes' states paid ``>= threshold`` (labelled
    ``depth``) and, with ``stall_label`` (R -> depth), the steps where they stalled below it (labelled by it)."""
    from drem_maniskill.drem.reward import DREMReward
    from drem_maniskill.experts import rollout
    from drem_maniskill.rl.run_env import make_eval_env
    from drem_maniskill.rl.run_policy import load_policy

    env = make_eval_env(dataclasses.replace(run, drem_form="paper"))
    reward = DREMReward.from_checkpoint(str(checkpoint), env)
    act = load_policy(run.run_dir).act(deterministic=False, seed=config.seed + k - 1)
    kept, stats = [], dict(episodes=0, failed=0, candidates=0, stalled=0, stall_candidates=0)
    try:
        for i in progress_bar(range(config.episodes), desc=f"round {k}: policy episodes"):
            steps = []

            def measure(env, obs, action, info, steps=steps):
                inputs = reward.inputs(env, None)
                steps.append(({m: v[:1].cpu().clone() for m, v in inputs.items()}, float(reward(inputs)[0])))
                return {}

            seed = 20_000 + 1_000 * k + i  # clear of the evaluation seeds (10,000 on) and the demo's
            ep = rollout(env, act, seed, max_episode_steps(run.task), stop_on_success=False, measure=measure)
            stats["episodes"] += 1
            if ep.success:
                continue
            stats["failed"] += 1
            traps = [(inputs, r, seed, t, depth) for t, (inputs, r) in enumerate(steps) if r >= threshold]
            stats["candidates"] += len(traps)
            kept += traps
            if stall_label is not None:
                stalled = [t for t in stalled_steps([r for _, r in steps], config.stall_window, config.stall_rise)
                           if steps[t][1] < threshold]
                stats["stalled"] += bool(stalled)
                stats["stall_candidates"] += len(stalled)
                kept += [(steps[t][0], steps[t][1], seed, t, stall_label(steps[t][1])) for t in stalled]
    finally:
        env.close()
    if len(kept) > config.max_negatives:
        kept = [kept[i] for i in np.linspace(0, len(kept) - 1, config.max_negatives).round().astype(int)]
    stats["negatives"] = len(kept)
    stats["reward_before"] = float(np.mean([row[1] for row in kept])) if kept else None
    return dict(stats=stats, rows=[row[:4] for row in kept], depths=[row[4] for row in kept])


def run_round(task: str, tree: str, checkpoint: Path, train_config, config: RoundsConfig, k: int, out: Path,
              negatives: list, trees: Sequence[str] = ()) -> tuple:
    """Round ``k`` from ``checkpoint``; returns ``(its checkpoint, its record)``, each stage resumed where it was."""
    from drem_maniskill.drem.checkpoint import load_checkpoint
    from drem_maniskill.pipeline.train_reward import train_reward
    from drem_maniskill.pipeline.tree.tree_file import start_depth
    from drem_maniskill.rl.train_policy import train_policy

    round_dir = out / f"round_{k}"
    round_dir.mkdir(parents=True, exist_ok=True)
    depth = config.depth(train_config.eps)
    run = round_policy_config(task, checkpoint, config, k, round_dir)
    record_path = round_dir / "collected.json"
    if not record_path.exists():
        result = train_policy(run)
        reward, data = tree_pay(checkpoint, tree)
        threshold = trap_threshold(reward, data, config, depth)
        stall_label = None
        if config.stall_window > 0:
            depths, paid = paid_by_depth(reward, data)
            stall_label = functools.partial(stall_depth, depths=depths, paid_curve=paid, eps=train_config.eps)
        del reward, data  # the tree's images: the episodes and the fine-tuning load their own
        label = config.trap_depth(train_config.eps, start_depth(Path(tree)))
        found = collect_negatives(run, checkpoint, threshold, config, k, label, stall_label)
        write_negatives(round_dir / "negatives.h5", found["rows"], found["depths"], train_config.model.cameras,
                        "ft" in train_config.model.modalities)
        last = result["last_eval"] or {}
        record = dict(round=k, sac_steps=run.steps, sac_success=last.get("success_rate"), negative_depth=depth,
                      trap_depth=label, threshold=round(threshold, 4), **found["stats"])
        write_json(record_path, record)
    record = json.loads(record_path.read_text())
    negatives = [*negatives, str(round_dir / "negatives.h5")]
    path = round_dir / "train" / "drem.pt"
    if not path.exists():
        header, _ = load_checkpoint(str(checkpoint))
        tuned = dataclasses.replace(train_config, iterations=config.iterations,
                                    save_every=min(train_config.save_every, config.iterations))
        train_reward(tree, str(round_dir / "train"), tuned, negatives=negatives, init_checkpoint=str(checkpoint),
                     extra_header=dict(rounds=[*header.get("rounds", []), record]), trees=trees)
        _record_after(path, round_dir / "negatives.h5")
    return path, negatives


@torch.no_grad()
def _record_after(path: Path, negatives: Path) -> None:
    """Add to the new checkpoint's last round what it pays that round's negatives (the round's effect)."""
    from drem_maniskill.drem.checkpoint import load_checkpoint, save_checkpoint
    from drem_maniskill.drem.reward import DREMReward

    header, weights = load_checkpoint(str(path))
    paid = paid_on_negatives(DREMReward(header, weights), negatives)
    after = float(paid.mean()) if len(paid) else None
    header["rounds"][-1]["reward_after"] = None if after is None else round(after, 4)
    save_checkpoint(str(path), header, weights)


def run_rounds(task: str, tree: str, checkpoint, train_config, config: RoundsConfig, out,
               trees: Sequence[str] = (), negatives: Sequence[str] = ()) -> Path:
    """Every round from ``checkpoint`` (trained on ``tree``, ``trees`` and the negatives files ``negatives``, which
    every round trains on too); the last round's checkpoint (``checkpoint`` with no rounds)."""
    out = Path(out)
    current, negatives = Path(checkpoint), list(negatives)
    for k in range(1, config.rounds + 1):
        current, negatives = run_round(task, tree, current, train_config, config, k, out, negatives, trees)
    return current
