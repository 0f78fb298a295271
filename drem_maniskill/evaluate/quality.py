"""``quality.json``: every measure of an examination's rollouts, as the model card reports them.

``quality`` takes what ``examine`` ran (the expert's episodes, each examination policy's episodes, the probes held
and the scene swaps at the expert's ends) and returns the file's dict; each group of measures has its own function.
docs/drem.md, "Examination", defines each measure; ``targets`` holds what each should reach.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np
from scipy.stats import spearmanr

from drem_maniskill.evaluate.measures import auroc, contact_loss_drop, contact_plateau, first_contact_loss
from drem_maniskill.evaluate.probes import (
    FACE_PUSHED, FLOOR_POSITION, HOLD_POSITIONS, SIDE_POSITION, SIDE_PUSHED, TURNED_HOVER, UPRIGHT_HOVER,
)
from drem_maniskill.evaluate.scene_swap import swap_ratios

FACE_OVER_HOVER = ("pressed 3 mm beside", "4 mm above, 4 mm off")

# ``<key>: (probe, base)``: the probe's mean reward over the base's. What each says:
HELD_RATIOS = {
    # What a policy gains by pressing the part on the floor instead of inserting it.
    "floor_beside_over_inserted": (FLOOR_POSITION, "inserted"),
    # The same for the part lowered beside the block's side, pushed into it and down, and pushed down on the face.
    "side_over_inserted": (SIDE_POSITION, "inserted"),
    "side_pushed_over_inserted": (SIDE_PUSHED, "inserted"),
    "face_pushed_over_inserted": (FACE_PUSHED, "inserted"),
    # Touching the face beside the opening over hovering above it as far off: below 1, a descent that misses the
    # opening by more than its clearance loses reward.
    "face_over_hover": FACE_OVER_HOVER,
    # The part turned about its axis and tilted over hovering upright at the same place: below 1, turning the part
    # away from the port loses reward.
    "turned_over_upright": (TURNED_HOVER, UPRIGHT_HOVER),
    "turned_over_inserted": (TURNED_HOVER, "inserted"),
    # Hovering at the opening 4 mm off its axis over hovering on it: at 1 or above, nothing pulls a policy onto the
    # axis for the last millimetres, and it stalls at the opening where the reward stops rising (measured: the
    # general recipe's SAC policies on SquarePegInHole-v1, docs/results.md).
    "mouth_off_axis_over_on_axis": ("4 mm above, 4 mm off", "4 mm above"),
}


def _pooled_spearman(episodes: list, key: str) -> float | None:
    """Spearman correlation of DREM reward with ``key`` over all steps of ``episodes``."""
    measured = [ep for ep in episodes if len(ep.get(key, [])) == len(ep["rewards"])]
    pairs = [(r, v) for ep in measured for r, v in zip(ep["rewards"], ep[key])]
    if len(pairs) < 3:
        return None
    a, b = np.array(pairs).T
    if np.ptp(a) == 0 or np.ptp(b) == 0:
        return None
    return float(spearmanr(a, b).correlation)


def _split_finals(curves: dict, policies: Sequence[str]) -> tuple:
    """The final-step rewards of ``policies``' episodes: ``(successful ones, failed ones)``."""
    finals = [(ep["rewards"][-1], ep["success"]) for p in policies for ep in curves.get(p, [])]
    return [r for r, s in finals if s], [r for r, s in finals if not s]


def _held_ratio(held: dict, position: str, base: str = "inserted") -> float | None:
    """A held position's mean reward over the finished insertion's, or ``base``'s (None where either is missing)."""
    if position not in held or not held.get(base, {}).get("mean"):
        return None
    return held[position]["mean"] / held[base]["mean"]


def order_and_separation(expert: list, curves: dict) -> dict:
    """The value-order correlation over the expert's successes, the final-step AUROCs, the Random policy's reward."""
    solved = [e for e in expert if e["success"]]
    rho = [spearmanr(np.arange(len(e["rewards"])), e["rewards"]).correlation for e in solved if len(e["rewards"]) > 2]
    finals = [(ep["rewards"][-1], ep["success"]) for eps in curves.values() for ep in eps]
    random_mean = float(np.mean([np.mean(ep["rewards"]) for ep in curves["random"]])) if "random" in curves else None
    return dict(
        value_order_spearman=float(np.nanmean(rho)) if rho else float("nan"),
        value_order_spearman_per_episode=[float(r) for r in rho],
        expert_success_rate=float(np.mean([e["success"] for e in expert])) if expert else float("nan"),
        final_reward_auroc=auroc([r for r, s in finals if s], [r for r, s in finals if not s]),
        # Without random actions, whose failures end far from anything: the expert's successes against the noisy
        # expert's failures, which end near the goal (ManiSkill's own tasks, which have a noisy expert; NaN when one
        # class is empty).
        final_reward_auroc_expert_noisy=auroc(*_split_finals(curves, ("direct_success", "noisy_expert")))
        if "noisy_expert" in curves else None,
        random_mean_reward=random_mean,
    )


def contact_measures(curves: dict) -> dict:
    """The paper's plateau and its drop at contact loss: Align Success on the face, Search Fail leaving it."""
    drops = [d for ep in curves.get("search_fail", []) if (d := contact_loss_drop(ep)) is not None]
    losses = [d for ep in curves.get("search_fail", []) if (d := first_contact_loss(ep)) is not None]
    direct = [ep["rewards"][-1] for ep in curves.get("direct_success", []) if ep["success"]]
    after_3 = [d["after_3"] for d in losses if d["after_3"] is not None]
    return dict(
        search_fail_contact_loss=dict(
            episodes_with_loss=len(drops),
            before=float(np.mean([d[0] for d in drops])) if drops else None,
            after=float(np.mean([d[1] for d in drops])) if drops else None,
        ),
        contact_plateau=contact_plateau(curves.get("align_success", []), float(np.mean(direct)) if direct else None),
        search_fail_first_contact_loss=dict(
            episodes_with_loss=len(losses),
            after_1=float(np.mean([d["after_1"] for d in losses])) if losses else None,
            after_3=float(np.mean(after_3)) if losses else None,
        ),
    )


def held_measures(held: dict) -> dict:
    """What colours do to the reward at the probes, the probes held, and each of ``HELD_RATIOS``."""
    spread = {k: v["std"] for k, v in held.items() if k != "inserted"}
    # The colour spread's target (docs/drem.md, "Examination") is over the places held above the opening.
    above = [spread[k] for k, target in HOLD_POSITIONS.items() if k in spread and target[2] > 0]
    return dict(
        colour_spread=dict(max_std=max(above) if above else None, per_position=spread),
        held_positions={k: {m: v[m] for m in ("mean", "std", "reached_error_mm")} for k, v in held.items()},
        inserted_reward_std=held["inserted"]["std"] if held else None,
        **{key: _held_ratio(held, *pair) for key, pair in HELD_RATIOS.items()},
    )


def correlations_and_curves(expert: list, curves: dict) -> dict:
    """Success rates, the reward's Spearman correlation with the task's own signals, and every reward curve."""
    # Over every step of the expert and examination rollouts.
    everything = expert + [ep for eps in curves.values() for ep in eps]
    return dict(
        success_rate={p: float(np.mean([ep["success"] for ep in eps])) for p, eps in curves.items()},
        spearman_with_normalized_dense=_pooled_spearman(everything, "normalized_dense"),
        spearman_with_insertion_depth=_pooled_spearman(everything, "insertion_depth"),
        spearman_with_normalized_dense_expert=_pooled_spearman(expert, "normalized_dense"),
        dense_curves={p: [ep["normalized_dense"] for ep in eps] for p, eps in curves.items()},
        curves={p: [ep["rewards"] for ep in eps] for p, eps in curves.items()},
        expert_curves=[e["rewards"] for e in expert],
    )


def quality(env_id: str, checkpoint: str, seeds: Sequence[int], expert: list, curves: dict, held: dict,
            swaps: Sequence[dict] = ()) -> dict:
    """The ``quality.json`` measures of the expert episodes, the policies' ``curves``, the ``held`` positions and the
    expert ends' ``scene_swap`` rows."""
    return dict(
        env_id=env_id, checkpoint=str(checkpoint), seeds=list(map(int, seeds)),
        **order_and_separation(expert, curves),
        # The expert's end with the robot there and everything else back at the start, over the end itself: near 1,
        # the reward pays the robot's pose whatever the task's objects do (docs/drem.md, "Examination").
        **swap_ratios(swaps),
        **contact_measures(curves),
        **held_measures(held),
        **correlations_and_curves(expert, curves),
    )
