"""What the examination reads from episodes: separation, the contact plateau, the drop at contact loss, the face's lead.

Each measure takes episodes as ``examine.examination_episode`` returns them (``rewards``, ``success``, ``force``,
``insertion_depth``, ``radial_offset``, one value per step) or rows as ``experiments/face_profile.py`` writes them.
docs/drem.md, "Examination", defines each.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np
from scipy.stats import spearmanr

from drem_maniskill.experts.scripted import CONTACT_FORCE

INSERTION_START = 0.001  # m below the top face: the part has started going in
AT_OPENING = 0.001  # m from the axis: the part is over the opening, not on the face beside it
FACE_LEAD_RANGE_MM = (0.5, 6.5)  # tip distances from the axis over which the face's lead is fitted


def auroc(scores_pos: Sequence[float], scores_neg: Sequence[float]) -> float:
    """Area under the ROC curve (Mann-Whitney U); NaN when a class is empty."""
    pos, neg = np.asarray(scores_pos, float), np.asarray(scores_neg, float)
    if len(pos) == 0 or len(neg) == 0:
        return float("nan")
    greater = (pos[:, None] > neg[None, :]).sum() + 0.5 * (pos[:, None] == neg[None, :]).sum()
    return float(greater / (len(pos) * len(neg)))


def contact_plateau(align: Sequence[dict], direct_final: float, contact: float = CONTACT_FORCE) -> dict:
    """Align Success's mean reward from its first contact to the start of insertion, over Direct Success's final reward.

    The paper's plateau: touching the face near the opening is progress, but short of the goal.
    Where the episodes hold ``radial_offset``, the same steps are also split into those on the face
    (tip more than ``AT_OPENING`` off the axis) and those at the opening (aligned, in its mouth but
    less than ``INSERTION_START`` in): the plateau averages both, and they read differently.
    """
    plateaus, steps = [], {"on_face": [], "at_opening": []}
    for ep in align:
        force, depth = np.asarray(ep["force"]), np.asarray(ep["insertion_depth"])
        touched = np.nonzero(force > contact)[0]
        if not len(touched):
            continue
        first = touched[0]
        inserting = np.nonzero(depth[first:] > INSERTION_START)[0]
        end = first + (inserting[0] if len(inserting) else len(depth) - first)
        if end > first:
            rewards = np.asarray(ep["rewards"][first:end], float)
            plateaus.append(float(rewards.mean()))
            if len(ep.get("radial_offset", [])) == len(depth):
                on_face = np.asarray(ep["radial_offset"][first:end]) > AT_OPENING
                steps["on_face"] += rewards[on_face].tolist()
                steps["at_opening"] += rewards[~on_face].tolist()
    mean = float(np.mean(plateaus)) if plateaus else None
    out = dict(episodes=len(plateaus), mean_reward=mean, direct_success_final=direct_final,
               fraction=None if mean is None or not direct_final else mean / direct_final)
    for key, rewards in steps.items():
        if rewards:
            out[key] = dict(steps=len(rewards), mean_reward=float(np.mean(rewards)),
                            fraction=float(np.mean(rewards)) / direct_final if direct_final else None)
    return out


def face_lead(rows: Sequence[dict], reward: str, start: float, inserted: float) -> dict:
    """How a reward reads the part pressed on the socket's face near the opening (``experiments/face_profile.py`` rows).

    ``rows``: ``{"tip_mm": [x, y, z], reward: {"values": [one per episode, same episodes in every row]}}``
    per held position (socket frame, z from the top face). Of the rows on the face (tip not below it
    by a millimetre) within ``FACE_LEAD_RANGE_MM`` of the axis:

    * ``to_go``: the mean fraction of the reward's rise from the start to a finished insertion
      still to go there (0 inserted, 1 start): what a policy resting on the face forgoes;
    * within each episode (its colours and placement), a line fitted to reward against distance
      from the axis: ``slope_per_mm`` (mean), ``spread`` (mean residual standard deviation), and
      ``lead = -slope_per_mm / spread``, the rise per millimetre towards the opening in units of
      that noise; ``order``, the mean Spearman correlation of reward with closeness to the axis
      (1: the reward always rises towards the opening). A policy on the face can follow a reward
      to the opening only where these are well above 0;
    * ``between_episodes``: the standard deviation of the episodes' mean rewards there (what
      colours and placement shift the whole face by, which a single episode does not see).
    """
    on_face = []
    for row in rows:
        x, y, z = row["tip_mm"]
        radial = float(np.hypot(x, y))
        if z > -1.0 and FACE_LEAD_RANGE_MM[0] <= radial <= FACE_LEAD_RANGE_MM[1]:
            on_face.append((radial, np.asarray(row[reward]["values"], float)))
    if len({r for r, _ in on_face}) < 3:
        return dict(positions=len(on_face), to_go=None, slope_per_mm=None, spread=None, lead=None, order=None,
                    between_episodes=None)
    r = np.array([p for p, _ in on_face])
    v = np.stack([vals for _, vals in on_face])  # [positions, episodes]
    slopes, spreads, orders = [], [], []
    for e in range(v.shape[1]):
        slope, offset = np.polyfit(r, v[:, e], 1)
        slopes.append(slope)
        spreads.append(np.std(v[:, e] - (slope * r + offset)))
        rho = spearmanr(-r, v[:, e]).correlation
        orders.append(0.0 if np.isnan(rho) else rho)
    slope, spread = float(np.mean(slopes)), float(np.mean(spreads))
    return dict(positions=len(on_face), to_go=float(np.mean((inserted - v) / (inserted - start))),
                slope_per_mm=slope, spread=spread, lead=float(-slope / max(spread, 1e-6)),
                order=float(np.mean(orders)), between_episodes=float(np.std(v.mean(0))))


def contact_losses(episode: dict, contact: float = CONTACT_FORCE) -> np.ndarray:
    """The steps whose wrist force reads below 1 N right after a step above ``contact``: where contact was lost."""
    f = np.asarray(episode["force"])
    return np.nonzero((f[:-1] > contact) & (f[1:] < 1.0))[0] + 1


def first_contact_loss(episode: dict, contact: float = CONTACT_FORCE) -> dict | None:
    """Search Fail's reward 1 and 3 steps after it first loses contact (step 1: the first reading without it)."""
    losses = contact_losses(episode, contact)
    if not len(losses):
        return None
    t, r = int(losses[0]), episode["rewards"]
    return dict(step=t, before=r[t - 1], after_1=r[t], after_3=r[t + 2] if t + 2 < len(r) else None)


def contact_loss_drop(episode: dict, contact: float = 3.0) -> tuple[float, float] | None:
    """Reward just before and just after the last fall of the wrist force below ``contact``."""
    losses = contact_losses(episode, contact)
    if not len(losses):
        return None
    t = int(losses[-1])
    return episode["rewards"][t - 1], episode["rewards"][t]
