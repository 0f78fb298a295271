"""The examination's probes (our tasks): places the part is held at, each a question put to the reward, in one table.

A probe holds the part's tip at a place (socket frame, metres, z up from the socket's top face) with ``HoldPolicy``
and reads the reward there, once per examination seed: each seed is a reset with the task's colour randomisation,
so a probe's spread over the seeds is what colours (and the few tenths of a millimetre the hold misses by) do to the
reward. Beside the probes, ``hold_positions`` reads ``inserted``: the scripted expert's finished insertion, held.
``examine.quality`` sets probes over ``inserted`` and over each other.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Optional, Sequence, Union

import numpy as np

from drem_maniskill.drem.wrapper import drem_source, reward_read_at_end
from drem_maniskill.envs.adapter import SocketGeometry
from drem_maniskill.experts import get_policy, rollout
from drem_maniskill.experts.scripted import PRESS_DEPTH, HoldPolicy
from drem_maniskill.utils.progress import progress_bar

FLOOR_BESIDE = 0.075  # m from the axis: clear of both sockets' blocks on the way down
SIDE_DOWN = 0.012  # m below the top face
SIDE_CLEAR = 0.002  # m between the part and the block's side
SIDE_PUSH = 0.008  # m the pushed hold aims below where it reaches the part down beside the block
TURNED_AT = (0.0028, -0.0078, 0.0034)  # m, socket frame
TURN = tuple(np.deg2rad([6.6, 8.9, -55.2]))  # rotation vector (socket frame, rad): tilted 11 deg, turned -55 deg

FLOOR_POSITION = f"pressed on the floor, {FLOOR_BESIDE * 1000:.0f} mm beside"
SIDE_POSITION = f"{SIDE_DOWN * 1000:.0f} mm down, {SIDE_CLEAR * 1000:.0f} mm beside the block's side"
SIDE_PUSHED = "pushed down against the block's side"
FACE_PUSHED = f"pushed down on the face beside the opening (aimed 3 mm off, {SIDE_PUSH * 1000:.0f} mm down)"
TURNED_HOVER = "3 mm above, 8 mm off, turned 55 deg"
UPRIGHT_HOVER = "3 mm above, 8 mm off"

HOLD_STEPS = 20  # steps to reach and settle at a position (about 1 cm per step at half speed)
TURN_STEPS = 30  # for a turned hold: the arm turns 2.9 deg a step at most, and TURN is 55 deg from the start's +-10

Point = Union[tuple, Callable]  # a place, or a function of the env that gives it


@dataclass(frozen=True)
class Probe:
    """A place the examination holds the part at, and what the reward read there tests."""

    name: str
    at: Point
    """The tip's target: socket frame, metres; or ``at(env)`` where the task's geometry places it."""
    tests: str
    """What the reward there tells, in one line."""
    via: Optional[Callable] = None
    """``via(env)``: the point, or points in order, the hold passes through first (``HoldPolicy(via=)``)."""
    turn: Optional[tuple] = None
    """The part's orientation, a rotation vector (socket frame, rad; ``HoldPolicy(turn=)``); None: upright."""
    colour_spread: bool = False
    """One of ``HOLD_POSITIONS``: above the face, its spread over episodes counts towards the colour spread."""

    def target(self, env) -> tuple:
        """The tip's target in ``env``."""
        return self.at(env) if callable(self.at) else self.at


def _beside_side(env) -> float:
    """Socket-frame x of the tip with the part ``SIDE_CLEAR`` outside the block's -x side."""
    return -(float(env.unwrapped.side_contact) + SIDE_CLEAR)


def _floor(env) -> tuple:
    """``FLOOR_BESIDE`` off the axis, pressed ``PRESS_DEPTH`` into the floor (the task's socket height down)."""
    return (0.0, -FLOOR_BESIDE, -(SocketGeometry.of_task(env.unwrapped).socket_height + PRESS_DEPTH))


def _side(env) -> tuple:
    """``SIDE_CLEAR`` outside the block's side, ``SIDE_DOWN`` below its top face."""
    return (_beside_side(env), 0.0, -SIDE_DOWN)


def _side_pushed(env) -> tuple:
    """A millimetre into the block's side, ``SIDE_PUSH`` below ``_side``: the hold pushes sideways and down."""
    # On USB the plug's overmould comes to rest on the block's top edge with its shell beside the block; on the peg
    # nothing stops the part before the target.
    return (-(float(env.unwrapped.side_contact) - 0.001), 0.0, -SIDE_DOWN - SIDE_PUSH)


def _above_side(env) -> tuple:
    """1 cm above the face, beside the block's side."""
    # Reached straight down from here: a line from the start would land on the top face.
    return (_beside_side(env), 0.0, 0.010)


def _down_the_side(env) -> tuple:
    """Above the block's side, then down it to just above ``_side``."""
    above = _above_side(env)
    return (above, (above[0], 0.0, -SIDE_DOWN + 0.001))


PROBES: tuple[Probe, ...] = (
    Probe("60 mm above", (0.0, 0.0, 0.060), "far above the opening: the approach barely begun", colour_spread=True),
    Probe("30 mm above", (0.0, 0.0, 0.030), "halfway down the approach", colour_spread=True),
    Probe("10 mm above", (0.0, 0.0, 0.010), "just above the opening", colour_spread=True),
    Probe("4 mm above", (0.0, 0.0, 0.004), "at the expert's pre-insertion height, centred", colour_spread=True),
    Probe("4 mm above, 1 mm off", (0.001, 0.0, 0.004), "as high, off the axis by about the clearance",
          colour_spread=True),
    Probe("4 mm above, 2 mm off", (0.002, 0.0, 0.004), "as high, off the axis by twice that", colour_spread=True),
    Probe("4 mm above, 4 mm off", (0.004, 0.0, 0.004), "as high, missing the opening: the hover the face is set over",
          colour_spread=True),
    Probe("pressed 3 mm beside", (0.003, 0.0, -PRESS_DEPTH),
          "pressed on the face beside the opening: contact is progress, short of the goal", colour_spread=True),
    Probe("25 mm down, 45 mm beside", (0.0, -0.045, -0.025),
          "as low as an inserted part, nowhere near the opening: height alone is not progress", colour_spread=True),
    Probe(FLOOR_POSITION, _floor, "pressed on the floor beside the socket: low and pushing, and no insertion"),
    Probe(SIDE_POSITION, _side, "lowered beside the block's side, touching nothing: below the face, not in the opening",
          via=_above_side),
    Probe(SIDE_PUSHED, _side_pushed, "pushed into the block's side and down: wrist force without insertion",
          via=_down_the_side),
    # As "pressed 3 mm beside", aiming SIDE_PUSH below the face: the part slides off the rim to 8-9 mm from the axis
    # (USB and peg alike) and pushes there with 20-25 N.
    Probe(FACE_PUSHED, (0.003, 0.0, -SIDE_PUSH), "pushed down hard on the face beside the opening"),
    Probe(TURNED_HOVER, TURNED_AT, "close over the opening, turned and tilted away from the port: a keyed part there "
          "cannot go in", turn=TURN),
    Probe(UPRIGHT_HOVER, TURNED_AT, "the same place upright: what turning the part away costs"),
)

# The fixed places around the opening; the colour spread is read over those above the face.
HOLD_POSITIONS = {p.name: p.at for p in PROBES if p.colour_spread}


def hold_targets(env) -> dict:
    """Every probe's tip target in ``env`` (``{name: (x, y, z)}``, in ``PROBES``' order)."""
    return {p.name: p.target(env) for p in PROBES}


def hold_vias(env) -> dict:
    """The points the probes with a ``via`` pass through first, in ``env`` (``HoldPolicy(via=)``)."""
    return {p.name: p.via(env) for p in PROBES if p.via is not None}


def hold_turns(env) -> dict:
    """The orientations of the probes not held upright (rotation vectors, socket frame; ``HoldPolicy(turn=)``)."""
    return {p.name: symmetric_turn(env, p.turn) for p in PROBES if p.turn is not None}


def symmetric_turn(env, turn: tuple) -> tuple:
    """``turn`` with its turn about the part's axis held to 3/4 of the way to the part's next fit.

    A part that fits every ``2 pi / k`` (``yaw_symmetry`` k >= 2) turned further would be turned towards, or past,
    its next fit: a hexagonal part turned 55 deg is 5 deg from fitting.
    """
    k = env.unwrapped.yaw_symmetry
    if k < 2:
        return turn
    limit = 0.75 * np.pi / k
    return (turn[0], turn[1], float(np.clip(turn[2], -limit, limit)))


def hold_length(turn: Optional[tuple], steps: int = HOLD_STEPS) -> int:
    """Steps a hold runs: ``steps``, and at least ``TURN_STEPS`` for a hold that turns the part (``turn`` not None)."""
    return steps if turn is None else max(steps, TURN_STEPS)


def end_reward(env, policy: Callable, seed: int, steps: Optional[int] = None, stop_on_success: bool = False) -> tuple:
    """``(the reward where an episode of policy ends, the episode)``: the same number as the episode's last reward.

    Where ``env`` is paid by a DREM reward (``drem.wrapper.drem_source``) the episode's steps skip it and it is read
    once, at the end (``drem.wrapper.reward_read_at_end``): a step's DREM reward renders the cameras, and only the
    last one is read. Any other reward is paid every step and the last one kept.
    """
    if drem_source(env) is None:
        ep = rollout(env, policy, int(seed), steps, stop_on_success=stop_on_success)
        return ep.rewards[-1], ep
    with reward_read_at_end(env) as read:
        ep = rollout(env, policy, int(seed), steps, stop_on_success=stop_on_success)
        return float(read().reshape(-1)[0]), ep


def hold_positions(env, seeds: Sequence[int], positions: dict = HOLD_POSITIONS, steps: int = HOLD_STEPS,
                   vias: dict | None = None, turns: dict | None = None) -> dict:
    """The reward with the tip held at each of ``positions`` (and the expert's insertion), per seed.

    The spread of one position's rewards across seeds is the *colour spread* (module docstring). Returns
    ``{position: {"rewards": [...], "mean", "std", "reached_error_mm"}}``.
    """
    out = {}
    for name, target in progress_bar(positions.items(), desc="examine: hold positions", unit="position"):
        rewards, errors = [], []
        for seed in seeds:
            turn = (turns or {}).get(name)
            policy = HoldPolicy(env, target, via=(vias or {}).get(name), turn=turn)
            rewards.append(end_reward(env, policy, seed, hold_length(turn, steps))[0])
            reached = env.unwrapped.tip_pose_in_socket().p[0].cpu().numpy()
            errors.append(float(np.linalg.norm(reached - np.asarray(target)) * 1000))
        out[name] = dict(rewards=rewards, mean=float(np.mean(rewards)), std=float(np.std(rewards)),
                         reached_error_mm=float(np.mean(errors)))
    rewards = []
    for seed in seeds:
        reward, ep = end_reward(env, get_policy("expert", env, seed=int(seed)), seed)
        if ep.success:
            rewards.append(reward)
    out["inserted"] = dict(rewards=rewards, mean=float(np.mean(rewards)) if rewards else None,
                           std=float(np.std(rewards)) if rewards else None, reached_error_mm=None)
    return out
