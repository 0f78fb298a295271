"""Measure a DREM reward: value-order correlation, examination policies, plots.

* **Value-order correlation**: mean Spearman correlation between the reward and the time step
  along expert episodes from held-out seeds (target >= 0.95).
* **Examination** (the paper's Fig. 4): reward against time for Direct Success, Align Success,
  Search Fail and Random; the AUROC of the final-step reward separating successful from failed
  episodes; the Random policy's mean reward (target <= 0.1); the reward just before and just
  after Search Fail loses contact.
* **The plateau, the drop, the colours** (our tasks): Align Success's reward on the face as a
  fraction of Direct Success's final one; Search Fail's reward 1 and 3 steps after it first
  loses contact; the reward with the tip held at fixed places (above the opening, off-centre,
  pressed beside it, inserted) in every episode's colours, and its spread over the episodes.
  docs/drem.md, "Examination", defines each.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Sequence

import gymnasium as gym
import numpy as np
from scipy.stats import spearmanr

from drem_maniskill.drem.wrapper import DREMRewardWrapper
from drem_maniskill.envs import is_insertion_task
from drem_maniskill.envs.adapter import SocketGeometry
from drem_maniskill.experts import ee_control_kwargs, get_policy, rollout
from drem_maniskill.experts.scripted import CONTACT_FORCE, PRESS_DEPTH, HoldPolicy
from drem_maniskill.experts.stock import STOCK_EXPERTS
from drem_maniskill.pipeline.scene_swap import scene_swap, swap_ratios
from drem_maniskill.utils.progress import progress_bar

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


def _make_env(env_id: str, checkpoint: str, env_kwargs: dict | None):
    """Our task with ``reward_mode="drem"``, or a stock task wrapped by ``DREMRewardWrapper``."""
    if is_insertion_task(env_id):
        return gym.make(
            env_id, obs_mode="state_dict", reward_mode="drem", drem_checkpoint=str(checkpoint), **(env_kwargs or {})
        )
    env = gym.make(env_id, obs_mode="state_dict", **ee_control_kwargs(env_id, env_kwargs))
    return DREMRewardWrapper(env, checkpoint)


# Where the examination holds the tip (socket frame, metres) to read the reward in every episode's
# colours: above the opening, off-centre above it, pressed on the face beside it, down beside the
# socket. "inserted" is the expert's finished insertion, held.
HOLD_POSITIONS = {
    "60 mm above": (0.0, 0.0, 0.060),
    "30 mm above": (0.0, 0.0, 0.030),
    "10 mm above": (0.0, 0.0, 0.010),
    "4 mm above": (0.0, 0.0, 0.004),
    "4 mm above, 1 mm off": (0.001, 0.0, 0.004),
    "4 mm above, 2 mm off": (0.002, 0.0, 0.004),
    "4 mm above, 4 mm off": (0.004, 0.0, 0.004),
    "pressed 3 mm beside": (0.003, 0.0, -PRESS_DEPTH),
    # Where SAC took the peg when trained on the reward from a one-placement tree: down beside the
    # socket, the part as low as an inserted one but nowhere near the opening.
    "25 mm down, 45 mm beside": (0.0, -0.045, -0.025),
}
FLOOR_BESIDE = 0.075  # m from the axis: clear of both sockets' blocks on the way down
FLOOR_POSITION = f"pressed on the floor, {FLOOR_BESIDE * 1000:.0f} mm beside"


SIDE_DOWN = 0.012  # m below the top face
SIDE_CLEAR = 0.002  # m between the part and the block's side
SIDE_POSITION = f"{SIDE_DOWN * 1000:.0f} mm down, {SIDE_CLEAR * 1000:.0f} mm beside the block's side"
SIDE_PUSH = 0.008  # m the pushed hold aims below where it reaches the part down beside the block
SIDE_PUSHED = "pushed down against the block's side"
FACE_PUSHED = f"pushed down on the face beside the opening (aimed 3 mm off, {SIDE_PUSH * 1000:.0f} mm down)"
# Where SAC held the plug on the USB reward of a tree with goal presses, side and push phases and no turn phase
# (docs/experiment-log.md, "Lineages caught in the opening"; experiments/exploit_rewards.py): 1-4 mm above the face,
# 2-10 mm off the axis, touching nothing, turned 13-55 deg about its axis and tilted 10-16 deg. That reward paid one
# such episode's last state 0.94 (an insertion 0.985), the same place upright 0.32, and 4 mm above, 4 mm off turned
# 40 deg either way 0.2-0.3: the pocket is narrow, so the hold is that state itself, and beside it the same place
# upright.
TURNED_AT = (0.0028, -0.0078, 0.0034)  # m, socket frame
TURN = tuple(np.deg2rad([6.6, 8.9, -55.2]))  # rotation vector (socket frame, rad): tilted 11 deg, turned -55 deg
TURNED_HOVER = "3 mm above, 8 mm off, turned 55 deg"
UPRIGHT_HOVER = "3 mm above, 8 mm off"


def hold_targets(env) -> dict:
    """``HOLD_POSITIONS`` plus the part pressed on the floor ``FLOOR_BESIDE`` beside the socket (the task's height),
    and the part ``SIDE_CLEAR`` beside the side of the socket's block, ``SIDE_DOWN`` below its top face.

    Where SAC took the part when trained on the rewards of trees without the outward phase
    (the sampler's ``outward`` phase): pressed on the floor a few centimetres beside the socket,
    which those rewards paid about as much as an insertion. And on USBInsertion-v1, trained on the
    reward of the ``--descend-from 0.006`` tree (docs/experiment-log.md, "A shorter approach above the port";
    ``experiments/exploit_rewards.py``): lowered along the block's side, 19-25 mm from the axis and
    11-23 mm down, which that reward paid 0.77-0.90.
    Then the part pushed into the block's side and down from there (``SIDE_PUSHED``), as that SAC policy
    held it: 50-110 N sideways and 50-130 N down at the wrist; on USB the plug's overmould comes to rest on
    the block's top edge with its shell beside the block (on the peg nothing stops it before the target).
    """
    u = env.unwrapped
    floor = -(SocketGeometry.of_task(u).socket_height + PRESS_DEPTH)
    # Reached straight down from above it (hold_vias): a line from the start would land on the top face.
    side = (_beside_side(env), 0.0, -SIDE_DOWN)
    pushed = (-(float(u.side_contact) - 0.001), 0.0, -SIDE_DOWN - SIDE_PUSH)
    # As "pressed 3 mm beside", aiming SIDE_PUSH below the face: the part slides off the rim to 8-9 mm from the
    # axis (USB and peg alike) and pushes there with 20-25 N (SAC's policy pushed 77 N, 1-3 mm off).
    face = (0.003, 0.0, -SIDE_PUSH)
    return {**HOLD_POSITIONS, FLOOR_POSITION: (0.0, -FLOOR_BESIDE, floor), SIDE_POSITION: side, SIDE_PUSHED: pushed,
            FACE_PUSHED: face, TURNED_HOVER: TURNED_AT, UPRIGHT_HOVER: TURNED_AT}


def hold_turns(env) -> dict:
    """Orientations (rotation vectors, socket frame; ``HoldPolicy(turn=)``) of the ``hold_targets`` not held upright."""
    return {TURNED_HOVER: TURN}


def _beside_side(env) -> float:
    """Socket-frame x of the tip with the part ``SIDE_CLEAR`` outside the block's -x side."""
    return -(float(env.unwrapped.side_contact) + SIDE_CLEAR)


def hold_vias(env) -> dict:
    """Points the hold of some ``hold_targets`` passes through first (``HoldPolicy(via=)``): above the block's side."""
    above = (_beside_side(env), 0.0, 0.010)
    return {SIDE_POSITION: above, SIDE_PUSHED: (above, (above[0], 0.0, -SIDE_DOWN + 0.001))}


HOLD_STEPS = 20  # steps to reach and settle at a position (about 1 cm per step at half speed)
TURN_STEPS = 30  # for a turned hold: the arm turns 2.9 deg a step at most, and TURN is 55 deg from the start's +-10
INSERTION_START = 0.001  # m below the top face: the part has started going in
AT_OPENING = 0.001  # m from the axis: the part is over the opening, not on the face beside it


def contact_plateau(align: Sequence[dict], direct_final: float, contact: float = CONTACT_FORCE) -> dict:
    """Align Success's mean reward from its first contact to the start of insertion, over Direct Success's final reward.

    The paper's plateau: touching the face near the opening is progress, but not yet the goal.
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


FACE_LEAD_RANGE_MM = (0.5, 6.5)  # tip distances from the axis over which the face's lead is fitted


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


def hold_positions(env, seeds: Sequence[int], positions: dict = HOLD_POSITIONS, steps: int = HOLD_STEPS,
                   vias: dict | None = None, turns: dict | None = None) -> dict:
    """The reward with the tip held at each of ``positions`` (and the expert's insertion), per seed.

    Each seed is a reset with the task's colour randomisation, so the spread of one position's
    rewards across seeds is what colours (and the few tenths of a millimetre the hold misses by)
    do to the reward: the *colour spread*. Returns ``{position: {"rewards": [...], "mean", "std",
    "reached_error_mm"}}``.
    """
    out = {}
    for name, target in progress_bar(positions.items(), desc="examine: hold positions", unit="position"):
        rewards, errors = [], []
        for seed in seeds:
            turn = (turns or {}).get(name)
            policy = HoldPolicy(env, target, via=(vias or {}).get(name), turn=turn)
            hold_steps = steps if turn is None else max(steps, TURN_STEPS)
            ep = rollout(env, policy, int(seed), hold_steps, stop_on_success=False)
            rewards.append(ep.rewards[-1])
            reached = env.unwrapped.tip_pose_in_socket().p[0].cpu().numpy()
            errors.append(float(np.linalg.norm(reached - np.asarray(target)) * 1000))
        out[name] = dict(rewards=rewards, mean=float(np.mean(rewards)), std=float(np.std(rewards)),
                         reached_error_mm=float(np.mean(errors)))
    rewards = []
    for seed in seeds:
        ep = rollout(env, get_policy("expert", env, seed=int(seed)), int(seed), stop_on_success=False)
        if ep.success:
            rewards.append(ep.rewards[-1])
    out["inserted"] = dict(rewards=rewards, mean=float(np.mean(rewards)) if rewards else None,
                           std=float(np.std(rewards)) if rewards else None, reached_error_mm=None)
    return out


def _held_ratio(held: dict, position: str, base: str = "inserted") -> float | None:
    """A held position's mean reward over the finished insertion's, or ``base``'s (None where either is missing)."""
    if position not in held or not held.get(base, {}).get("mean"):
        return None
    return held[position]["mean"] / held[base]["mean"]


FACE_OVER_HOVER = ("pressed 3 mm beside", "4 mm above, 4 mm off")


def contact_loss_drop(episode: dict, contact: float = 3.0) -> tuple[float, float] | None:
    """Reward just before and just after the last fall of the wrist force below ``contact``."""
    losses = contact_losses(episode, contact)
    if not len(losses):
        return None
    t = int(losses[-1])
    return episode["rewards"][t - 1], episode["rewards"][t]


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
    result = _quality(env_id, checkpoint, seeds, expert, curves, held, swaps)
    if out_dir:
        out = Path(out_dir)
        out.mkdir(parents=True, exist_ok=True)
        plot_examination(result, out / "examination.png")
        tmp = out / ".quality.json.tmp"
        tmp.write_text(json.dumps(result, indent=1))
        os.replace(tmp, out / "quality.json")
    return result


def _split_finals(curves: dict, policies: Sequence[str]) -> tuple:
    """The final-step rewards of ``policies``' episodes: ``(successful ones, failed ones)``."""
    finals = [(ep["rewards"][-1], ep["success"]) for p in policies for ep in curves.get(p, [])]
    return [r for r, s in finals if s], [r for r, s in finals if not s]


def _quality(env_id: str, checkpoint: str, seeds: Sequence[int], expert: list, curves: dict, held: dict,
             swaps: Sequence[dict] = ()) -> dict:
    """The ``quality.json`` measures of the expert episodes, the policies' ``curves``, the ``held`` positions and the
    expert ends' ``scene_swap`` rows."""
    solved = [e for e in expert if e["success"]]
    rho = [spearmanr(np.arange(len(e["rewards"])), e["rewards"]).correlation for e in solved if len(e["rewards"]) > 2]
    finals = [(ep["rewards"][-1], ep["success"]) for eps in curves.values() for ep in eps]
    drops = [d for ep in curves.get("search_fail", []) if (d := contact_loss_drop(ep)) is not None]
    losses = [d for ep in curves.get("search_fail", []) if (d := first_contact_loss(ep)) is not None]
    direct = [ep["rewards"][-1] for ep in curves.get("direct_success", []) if ep["success"]]
    spread = {k: v["std"] for k, v in held.items() if k != "inserted"}
    # The colour spread's target (docs/drem.md, "Examination") is over the places held above the opening.
    above = [spread[k] for k, target in HOLD_POSITIONS.items() if k in spread and target[2] > 0]
    random_mean = float(np.mean([np.mean(ep["rewards"]) for ep in curves["random"]])) if "random" in curves else None
    after_3 = [d["after_3"] for d in losses if d["after_3"] is not None]
    everything = expert + [ep for eps in curves.values() for ep in eps]
    return dict(
        env_id=env_id, checkpoint=str(checkpoint), seeds=list(map(int, seeds)),
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
        # The expert's end with the robot there and everything else back at the start, over the end itself: near 1,
        # the reward pays the robot's pose whatever the task's objects do (docs/drem.md, "Examination").
        **swap_ratios(swaps),
        search_fail_contact_loss=dict(
            episodes_with_loss=len(drops),
            before=float(np.mean([d[0] for d in drops])) if drops else None,
            after=float(np.mean([d[1] for d in drops])) if drops else None,
        ),
        # The paper's plateau, its drop at contact loss, and what colours do (docs/drem.md, "Examination").
        contact_plateau=contact_plateau(curves.get("align_success", []), float(np.mean(direct)) if direct else None),
        search_fail_first_contact_loss=dict(
            episodes_with_loss=len(losses),
            after_1=float(np.mean([d["after_1"] for d in losses])) if losses else None,
            after_3=float(np.mean(after_3)) if losses else None,
        ),
        colour_spread=dict(max_std=max(above) if above else None, per_position=spread),
        held_positions={k: {m: v[m] for m in ("mean", "std", "reached_error_mm")} for k, v in held.items()},
        inserted_reward_std=held["inserted"]["std"] if held else None,
        # What a policy gains by pressing the part on the floor instead of inserting it (the trap SAC found).
        floor_beside_over_inserted=_held_ratio(held, FLOOR_POSITION),
        # The same for the part lowered beside the block's side, and pushed into it and down (the trap SAC
        # found on the --descend-from USB reward), and pushed down on the face.
        side_over_inserted=_held_ratio(held, SIDE_POSITION),
        side_pushed_over_inserted=_held_ratio(held, SIDE_PUSHED),
        face_pushed_over_inserted=_held_ratio(held, FACE_PUSHED),
        # Touching the face beside the opening over hovering above it as far off: below 1, a descent that misses the
        # opening by more than its clearance loses reward (the valley SAC stopped above on the side + push USB reward).
        face_over_hover=_held_ratio(held, *FACE_OVER_HOVER),
        # The part turned about its axis and tilted over hovering upright at the same place: below 1, turning the part
        # away from the port loses reward (the hover SAC settled in on a USB reward without the turn phase, which no
        # upright hold reached).
        turned_over_upright=_held_ratio(held, TURNED_HOVER, UPRIGHT_HOVER),
        turned_over_inserted=_held_ratio(held, TURNED_HOVER),
        success_rate={p: float(np.mean([ep["success"] for ep in eps])) for p, eps in curves.items()},
        # Over every step of the expert and examination rollouts.
        spearman_with_normalized_dense=_pooled_spearman(everything, "normalized_dense"),
        spearman_with_insertion_depth=_pooled_spearman(everything, "insertion_depth"),
        spearman_with_normalized_dense_expert=_pooled_spearman(expert, "normalized_dense"),
        dense_curves={p: [ep["normalized_dense"] for ep in eps] for p, eps in curves.items()},
        curves={p: [ep["rewards"] for ep in eps] for p, eps in curves.items()},
        expert_curves=[e["rewards"] for e in expert],
    )


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
        # The reward with the tip held in place, mean and spread over episodes (colours randomised).
        ax = axes[0, -1]
        x = np.arange(len(held))
        ax.bar(x, [v["mean"] for v in held.values()], yerr=[v["std"] for v in held.values()], capsize=3, color="C7")
        ax.set_xticks(x, list(held), rotation=40, ha="right", fontsize=7)
        ax.set_ylabel("DREM reward, tip held (mean, std over episodes)")
        spread = result.get("colour_spread", {}).get("max_std")
        ax.set_title(f"colour spread: largest std {spread:.3f}" if spread is not None else "held positions")
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
