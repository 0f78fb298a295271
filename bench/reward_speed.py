"""DREM speed, measured side by side in one run and printed as ratios.

1. Reward cost: an ``obs_mode="rgb"`` env step with ``reward_mode="drem"`` against the same
   step with ``reward_mode="none"`` (target: DREM adds at most 15 %), one env switched between
   the two (and the straightforward path) step by step; and the reward's own time in the step.
2. Backward sampling: children per second (restore the seed state, step, render) against
   plain ``rgb`` env steps per second (target: at least 0.7).
3. Reward-model training: samples per second on this CPU (forward, backward, Adam step).

Run: ``.venv/bin/python bench/reward_speed.py --checkpoint rewards/PegInHole-v1/drem.pt``
(``--quick`` for a smoke run, ``--parts reward`` for the first measurement only). Writes the
numbers to ``--out`` as JSON too. The reward is measured twice: as shipped, and through the
straightforward ``model.encode(model.prepare(...))`` path it replaced, in the same run.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import time
from pathlib import Path

import gymnasium as gym
import numpy as np
import torch

import drem_maniskill  # noqa: F401
from drem_maniskill.drem.checkpoint import resolve_checkpoint
from drem_maniskill.drem.model import DREMModel, ModelConfig, cosine_distance
from drem_maniskill.pipeline.losses import reconstruction_loss
from drem_maniskill.pipeline.tree.child_sampler import ChildSampler


def time_steps(env, steps: int, seed: int = 0) -> list:
    """Per-step wall times of random-action steps (reset when an episode ends)."""
    env.reset(seed=seed)
    gen = torch.Generator().manual_seed(seed)
    times = []
    for _ in range(steps):
        action = torch.rand(1, 6, generator=gen) * 2 - 1
        t = time.perf_counter()
        _, _, terminated, truncated, _ = env.step(action)
        times.append(time.perf_counter() - t)
        if bool(terminated.any() or truncated.any()):
            env.reset()
    return times


def bench_reward(task: str, checkpoint: str, steps: int) -> dict:
    """Median step times of one env switched step by step between no reward and DREM (then its straightforward path)."""
    env = gym.make(task, obs_mode="rgb", reward_mode="drem", drem_checkpoint=checkpoint)
    u = env.unwrapped
    reward = u.drem_reward
    # One env instance for all three, switched between steps: two instances differed by about
    # 0.5 ms a step here, a third of what is measured.
    modes = {
        "none": ("none", reward.forward),
        "drem": ("drem", reward.forward),
        # The same reward through model.encode(model.prepare(...)): what the fast encoder replaced.
        "straight": ("drem", reward.forward_reference),
    }
    reward_times, timing = [], [False]
    inner = u.compute_drem_reward

    def timed_reward(**kwargs):
        # The reward's own time inside each step.
        t = time.perf_counter()
        out = inner(**kwargs)
        if timing[0]:
            reward_times.append(time.perf_counter() - t)
        return out

    u.compute_drem_reward = timed_reward
    # Two rounds, each alternating blocks of plain steps and steps with the reward; the first
    # step of a block is not timed, so no timed step follows one of the other kind (a step with
    # the straightforward reward slows the plain step after it: its memory traffic).
    times = {"none": [], "drem": [], "none_2": [], "straight": []}
    blocks = {"none": [], "drem": [], "none_2": [], "straight": []}  # per-block medians
    env.reset(seed=0)
    gen = torch.Generator().manual_seed(0)
    block = 5
    for pair in (("none", "drem"), ("none_2", "straight")):
        for k in range(2 * block * (steps // (block - 1) + 2)):
            mode = pair[k // block % 2]
            u._reward_mode, reward.forward = modes[mode.split("_")[0]]
            timing[0] = mode == "drem"
            action = torch.rand(1, 6, generator=gen) * 2 - 1
            t = time.perf_counter()
            _, _, terminated, truncated, _ = env.step(action)
            if k % block and k >= 2 * block:  # not the first of a block, nor the first round
                times[mode].append(time.perf_counter() - t)
                if k % block == block - 1:
                    blocks[mode].append(statistics.median(times[mode][1 - block :]))
            if bool(terminated.any() or truncated.any()):
                env.reset()
    env.close()
    pa, pb, pa2, pc = (statistics.median(times[m]) for m in times)
    pr = statistics.median(reward_times[4:])

    def paired(base, case):
        # Each block against the plain block just before it: the machine's speed drifts over a
        # run (here by 20 % between runs), and neighbouring blocks share the drift.
        diffs = [(b - a) / a for a, b in zip(blocks[base], blocks[case])]
        return statistics.median(diffs), statistics.quantiles(diffs, n=4)[::2]

    (overhead, overhead_iqr) = paired("none", "drem")
    return dict(
        drem_overhead=overhead, drem_overhead_quartiles=overhead_iqr,
        rgb_step_ms=pa * 1e3, drem_step_ms=pb * 1e3, reward_in_step_ms=pr * 1e3, reward_share=pr / pa,
        drem_straight_step_ms=pc * 1e3, drem_straight_overhead=paired("none_2", "straight")[0],
        steps_each=len(times["none"]), block_pairs=len(blocks["drem"]), threads=torch.get_num_threads(),
        load_avg=os.getloadavg()[0],
    )


def bench_sampling(task: str, steps: int) -> dict:
    """Children per second of the sampler against plain rgb steps per second."""
    env = gym.make(task, obs_mode="rgb", reward_mode="none")
    sampler = ChildSampler(task, {}, 0)
    seed_state = sampler.unwrapped.get_state_dict()
    rng = np.random.default_rng(0)
    sampler.children(seed_state, rng.uniform(-1, 1, size=(4, 6)))  # warm-up
    time_steps(env, 5)
    t_children, t_steps = 0.0, 0.0
    for r in range(4):
        t = time.perf_counter()
        sampler.children(seed_state, rng.uniform(-1, 1, size=(steps // 4, 6)))
        t_children += time.perf_counter() - t
        t_steps += sum(time_steps(env, steps // 4, seed=r))
    sampler.close(), env.close()
    children_s, steps_s = steps / t_children, steps / t_steps
    return dict(children_per_s=children_s, rgb_steps_per_s=steps_s, ratio=children_s / steps_s)


def bench_training(image_size: int, pairs: int, iterations: int) -> dict:
    """Training samples per second for the model as configured by the training presets."""
    model = DREMModel(ModelConfig(image_size=image_size))
    opt = torch.optim.Adam(model.parameters(), lr=2e-4)
    n = 2 * pairs + 1
    batch = {c: torch.randint(0, 255, (n, image_size, image_size, 3), dtype=torch.uint8) for c in ("fixed", "wrist")}
    batch["ft"] = torch.randn(n, 8, 6)
    times = []
    for k in range(iterations + 3):
        t = time.perf_counter()
        h, recon, inputs = model(batch)
        loss = cosine_distance(h[:-1], h[-1:]).mean() + 0.2 * reconstruction_loss(recon, inputs)
        opt.zero_grad(set_to_none=True)
        loss.backward()
        opt.step()
        if k >= 3:  # the first calls pay for oneDNN's kernel set-up
            times.append(time.perf_counter() - t)
    return dict(image_size=image_size, samples_per_iteration=n, samples_per_s=n / statistics.median(times),
                threads=torch.get_num_threads())


def main() -> None:
    """Run the three measurements and print them with their ratios."""
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--task", default="PegInHole-v1")
    parser.add_argument("--checkpoint", default=None, help="default: the shipped one for --task")
    parser.add_argument("--steps", type=int, default=300, help="steps per measured case")
    parser.add_argument("--quick", action="store_true")
    parser.add_argument("--out", default="outputs/bench/reward_speed.json")
    parts = ("reward", "sampling", "training")
    parser.add_argument("--parts", nargs="+", choices=parts, default=parts)
    args = parser.parse_args()
    steps = 8 if args.quick else args.steps
    checkpoint = str(resolve_checkpoint(args.task, args.checkpoint))
    res = dict(task=args.task, checkpoint=checkpoint)
    print(f"task {args.task}, checkpoint {checkpoint}")
    if "reward" in args.parts:
        r = res["reward"] = bench_reward(args.task, checkpoint, steps)
        print(f"rgb env step            {r['rgb_step_ms']:7.1f} ms   "
              f"({r['threads']} torch threads, load average {r['load_avg']:.2f})")
        print(f"DREM reward in the step {r['reward_in_step_ms']:7.1f} ms   "
              f"-> {100 * r['reward_share']:.1f} % of the rgb step (target <= 15 %)")
        low, high = (100 * q for q in r["drem_overhead_quartiles"])
        print(f"rgb env step + DREM     {r['drem_step_ms']:7.1f} ms   -> step-time difference "
              f"{100 * r['drem_overhead']:.1f} % (same env, median of {r['block_pairs']} paired blocks; "
              f"quartiles {low:.0f} to {high:.0f} %)")
        print(f"  straightforward path  {r['drem_straight_step_ms']:7.1f} ms   "
              f"-> adds {100 * r['drem_straight_overhead']:.1f} % (model.encode(model.prepare(...)))")
    if "sampling" in args.parts:
        s = res["sampling"] = bench_sampling(args.task, steps)
        print(f"sampler children        {s['children_per_s']:7.1f} /s")
        print(f"plain rgb env steps     {s['rgb_steps_per_s']:7.1f} /s   -> ratio {s['ratio']:.2f} (target >= 0.7)")
    if "training" in args.parts:
        res["training"] = {str(s): bench_training(s, 16, 2 if args.quick else 10) for s in (64, 128)}
        for size, t in res["training"].items():
            print(f"training at {size:>3} px      {t['samples_per_s']:7.1f} samples/s "
                  f"({t['samples_per_iteration']} per iteration, {t['threads']} threads)")
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_suffix(".tmp")
    tmp.write_text(json.dumps(res, indent=2))
    os.replace(tmp, out)


if __name__ == "__main__":
    main()
