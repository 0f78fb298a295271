"""The examination's held positions: the reward read where each hold ends against the reward paid every step.

A held position is read once, at the hold's end (``evaluate.probes.end_reward``: the hold runs in the ``none``
reward mode, so its steps render nothing). Paying the reward every step renders both cameras at every step and
gives the same number at the end (``tests/evaluate/test_probes.py``). One env, the probes in turn, each held both
ways one after the other (A: read at the end, B: paid every step), so drift in the machine's speed falls on both;
the ratio is of the summed times.

Run: ``.venv/bin/python bench/hold_speed.py --task PegInHole-v1 --seeds 0 1 --out docs/results/bench/hold_speed.json``
"""

from __future__ import annotations

import argparse
import json
import time
import warnings
from pathlib import Path

import gymnasium as gym

import drem_maniskill  # noqa: F401
from drem_maniskill.evaluate.probes import (
    HOLD_STEPS, PROBES, end_reward, hold_length, hold_targets, hold_turns, hold_vias,
)
from drem_maniskill.experts import rollout
from drem_maniskill.experts.scripted import HoldPolicy


def main(argv=None) -> dict:
    """Time every probe's hold both ways; print and write the sums and their ratio."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--task", default="PegInHole-v1")
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1])
    parser.add_argument("--out", default=None)
    args = parser.parse_args(argv)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        env = gym.make(args.task, obs_mode="state_dict", reward_mode="drem")
    targets, vias, turns = hold_targets(env), hold_vias(env), hold_turns(env)
    times = {"end": 0.0, "every_step": 0.0}
    try:
        end_reward(env, HoldPolicy(env, targets[PROBES[0].name]), args.seeds[0], HOLD_STEPS)  # the first pictures
        for probe in PROBES:
            for seed in args.seeds:
                steps = hold_length(turns.get(probe.name))

                def policy():
                    return HoldPolicy(env, targets[probe.name], via=vias.get(probe.name), turn=turns.get(probe.name))

                t = time.perf_counter()
                end_reward(env, policy(), seed, steps)
                times["end"] += time.perf_counter() - t
                t = time.perf_counter()
                rollout(env, policy(), seed, steps, stop_on_success=False)
                times["every_step"] += time.perf_counter() - t
    finally:
        env.close()
    result = dict(task=args.task, seeds=args.seeds, probes=len(PROBES),
                  seconds={k: round(v, 2) for k, v in times.items()},
                  end_over_every_step=round(times["end"] / times["every_step"], 3))
    print(json.dumps(result, indent=1))
    if args.out:
        Path(args.out).write_text(json.dumps(result, indent=1) + "\n")
    return result


if __name__ == "__main__":
    main()
