"""SAC wall-clock per 1,000 env steps for each reward, the reward's share of it, and its ratio to the env alone.

For each preset and reward: build the run's env and SAC exactly as ``train-policy`` does, take
``--warmup`` random steps (``learning_starts``), then time ``--steps`` SAC steps (at the config's update
ratio: ``train_freq``, ``gradient_steps``). The reward's cost is measured two ways, printed side by side:

* in-step timer: the time inside the env's ``get_reward`` (VICE: inside its wrapper, around the
  inner env step), plus VICE's classifier updates amortised over ``update_every`` steps;
* step difference: random-action env steps of this env against the same env with
  ``reward_mode="none"`` (this carries about 0.5 ms of noise per step).

``x_env`` is the run's wall time over the plain env's own stepping (``gym.make(task, obs_mode="rgb",
reward_mode="none")``, random actions, measured in the same run): the targets are 2x for the
``state`` preset with the drem reward and 3x for ``light`` and ``image`` (every reward). ``grad_ms`` is
SAC's gradient step (SB3's ``train``), per env step. A run with ``overlap_env`` (``overlapped``) steps its
env in a child process while the gradient step runs, as ``train-policy`` does: its reward and step-difference columns
are measured in the child.

    .venv/bin/python bench/sac_speed.py                          # light preset, every reward
    .venv/bin/python bench/sac_speed.py --presets state light --rewards drem  # the two targeted ratios
    .venv/bin/python bench/sac_speed.py --presets image     # the image comparison's preset, every reward
    .venv/bin/python bench/sac_speed.py --presets light paper --paper-steps 20
    .venv/bin/python bench/sac_speed.py --rewards drem --encoders separate shared   # rl.sac's shared encoder
    .venv/bin/python bench/sac_speed.py --presets state light --rewards drem \
        --variants preset train_freq=4 net_arch=128+128,batch_size=128
    .venv/bin/python bench/sac_speed.py --presets state --rewards drem \
        --variants preset overlap_env=0 overlap_env=0,train_bf16=0
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time
from pathlib import Path

os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

import torch  # noqa: E402

from drem_maniskill.rl.config import PRESETS, RLConfig  # noqa: E402
from drem_maniskill.rl.algos import algo_spec  # noqa: E402
from drem_maniskill.rl.rewards import REWARDS  # noqa: E402
from drem_maniskill.rl.run_env import make_vec_env  # noqa: E402
from drem_maniskill.rl.vec_env import SubprocDictVecEnv  # noqa: E402


class Timer:
    """Accumulates the time of the calls of one function."""

    def __init__(self, fn):
        self.fn, self.total, self.calls = fn, 0.0, 0

    def __call__(self, *args, **kwargs):
        t = time.perf_counter()
        try:
            return self.fn(*args, **kwargs)
        finally:
            self.total += time.perf_counter() - t
            self.calls += 1


def random_step_ms(env, n: int) -> float:
    """Mean ms per env step (policy-observation wrapper included) with random actions."""
    env.reset(seed=123)
    t = time.perf_counter()
    for i in range(n):
        env.step(torch.as_tensor(env.action_space.sample()))
        if (i + 1) % 50 == 0:
            env.reset()
    return 1000 * (time.perf_counter() - t) / n


def time_reward(venv, reset: bool = False) -> float:
    """In an env's child process: time the reward's calls from now (first call) and return their total seconds."""
    u = venv.base_env
    if not isinstance(u.get_reward, Timer):
        u.get_reward = Timer(u.get_reward)
    if reset:
        u.get_reward.total = 0.0
    return u.get_reward.total


def child_step_ms(venv, n: int) -> float:
    """``random_step_ms`` of a ``ManiSkillDictVecEnv``'s env (in an env's child process, through ``call``)."""
    return random_step_ms(venv._env, n)


def parse_variant(text: str) -> dict:
    """``"net_arch=128+128,batch_size=128"`` -> RLConfig overrides (integers; ``+`` joins a tuple); ``preset``: none."""
    if text == "preset":
        return {}
    out = {}
    for item in text.split(","):
        key, sep, value = item.partition("=")
        if not sep:
            raise SystemExit(f"--variants: {item!r} is not KEY=VALUE (e.g. train_freq=4 or net_arch=128+128)")
        out[key] = tuple(int(v) for v in value.split("+")) if "+" in value else int(value)
    return out


def measure(preset: str, reward: str, task: str, steps: int, warmup: int, env_steps: int, none_ms: float,
            plain_ms: float, encoder: str = "preset", variant: str = "preset") -> dict:
    """Time one reward in one preset (``encoder``: the preset's, ``separate`` or ``shared``; ``variant``: RLConfig
    overrides as ``parse_variant`` reads them, or ``preset``); one table row."""
    overrides = {} if encoder == "preset" else dict(shared_encoder=encoder == "shared")
    overrides.update(parse_variant(variant))
    config = RLConfig.from_preset(preset, task=task, reward=reward, steps=warmup + steps, learning_starts=warmup,
                                  reward_kwargs=dict(seed=0, goal_seeds=3), out=tempfile.mkdtemp(), **overrides)
    torch.set_num_threads(config.threads)
    venv, vice = make_vec_env(config)  # as train-policy builds it
    # Overlapped: the env in a child process, stepping while the gradient step runs here.
    overlapped = isinstance(venv, SubprocDictVecEnv)
    if overlapped:
        venv.call(time_reward)
    elif vice is not None:
        inner, outer = Timer(vice.env.step), Timer(vice.step)
        vice.env.step, vice.step = inner, outer
        reward_timer = None
    else:
        u = venv.base_env
        reward_timer = u.get_reward = Timer(u.get_reward)
    model = algo_spec(config.algo).build(config, venv)
    if overlapped:
        model.train_while_env_steps(venv)
    model.learn(total_timesteps=warmup)  # random actions, no gradient steps yet
    grad_timer = model.train = Timer(model.train)
    if overlapped:
        venv.call(time_reward, True)
    elif reward_timer is not None:
        reward_timer.total = reward_timer.calls = 0
    else:
        inner.total = outer.total = 0.0
    env0 = venv.env_time
    t = time.perf_counter()
    model.learn(total_timesteps=steps, reset_num_timesteps=False)
    total = time.perf_counter() - t
    env_time = venv.env_time - env0
    if overlapped:
        reward_time = venv.call(time_reward)
    else:
        reward_time = reward_timer.total if reward_timer is not None else outer.total - inner.total
    vice_update_s = 0.0
    if vice is not None:
        # Classifier updates run every update_every steps (1000): time one and amortise it.
        t = time.perf_counter()
        vice.update()
        vice_update_s = time.perf_counter() - t
        reward_time += vice_update_s * steps / vice.config.update_every
    step_ms = venv.call(child_step_ms, env_steps) if overlapped else child_step_ms(venv, env_steps)
    venv.close()
    per_k = 1000 * total / steps
    return dict(
        preset=preset, reward=reward, encoder="shared" if config.shared_encoder else "separate", task=task, steps=steps,
        variant=variant, update_ratio=config.gradient_steps / config.train_freq, bf16=config.train_bf16,
        overlapped=overlapped,
        net_arch="x".join(map(str, config.net_arch)), batch_size=config.batch_size,
        sac_s_per_1k=round(per_k, 1), env_steps_per_min=round(60 * steps / total, 1),
        plain_env_s_per_1k=round(plain_ms, 2), x_env=round(per_k / plain_ms, 2),
        grad_ms=round(1000 * grad_timer.total / steps, 2),
        env_share=round(env_time / total, 3),
        reward_s_per_1k=round(1000 * reward_time / steps, 2), reward_share=round(reward_time / total, 4),
        vice_update_s=round(vice_update_s, 3),
        step_ms=round(step_ms, 2), step_ms_none=round(none_ms, 2),
        step_diff_share=round(max(step_ms - none_ms, 0.0) * steps / 1000 / total, 4),
    )


def main(argv=None) -> int:
    """Run the benchmark; print the table and write JSON."""
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--presets", nargs="+", default=["light"], choices=list(PRESETS))
    p.add_argument("--rewards", nargs="+", default=list(REWARDS))
    p.add_argument("--task", default="PegInHole-v1")
    p.add_argument("--steps", type=int, default=300, help="timed SAC steps per reward, CPU presets")
    p.add_argument("--paper-steps", type=int, default=20, help="timed SAC steps per reward, paper preset")
    p.add_argument("--warmup", type=int, default=256, help="random steps first (also the first batches)")
    p.add_argument("--env-steps", type=int, default=100, help="random env steps for the step-difference measure")
    p.add_argument("--encoders", nargs="+", default=["preset"], choices=["preset", "separate", "shared"],
                   help="image presets: the preset's extractor layout, SB3's separate ones, or one shared (rl.sac)")
    p.add_argument("--variants", nargs="+", default=["preset"],
                   help="RLConfig overrides, one row each: KEY=VALUE[,KEY=VALUE], + joins a tuple "
                        "(e.g. train_freq=4 net_arch=128+128,batch_size=128); preset: none")
    p.add_argument("--out", default="outputs/bench/sac_speed.json")
    args = p.parse_args(argv)
    import drem_maniskill  # noqa: F401

    import gymnasium as gym

    from drem_maniskill.rl.observation import PolicyObservation, state_parts

    # The yardstick of x_env: the task's own rgb env, nothing else (ms per step = s per 1,000 steps).
    plain = gym.make(args.task, obs_mode="rgb", reward_mode="none", sim_backend="cpu")
    plain_ms = random_step_ms(plain, args.env_steps)
    plain.close()
    rows = []
    for preset in args.presets:
        # The reference: the same observation pipeline with reward_mode "none".
        none_cfg = RLConfig.from_preset(preset, task=args.task, reward="sparse")
        obs_mode = "rgb" if none_cfg.uses_images else "state_dict"
        none_env = PolicyObservation(gym.make(args.task, obs_mode=obs_mode, reward_mode="none", sim_backend="cpu"),
                                     none_cfg.image_size, none_cfg.cameras, ft=True, state=none_cfg.policy_state,
                                     state_keys=state_parts(none_cfg.policy_qvel, none_cfg.policy_privileged))
        none_ms = random_step_ms(none_env, args.env_steps)
        none_env.close()
        steps = args.paper_steps if preset == "paper" else args.steps
        # The state preset has no camera, so no encoder to share.
        encoders = ["preset"] if preset == "state" else args.encoders
        for reward in args.rewards:
            for encoder in encoders:
                for variant in args.variants:
                    try:
                        row = measure(preset, reward, args.task, steps, args.warmup, args.env_steps, none_ms, plain_ms,
                                      encoder, variant)
                    except FileNotFoundError as err:  # drem-image without its checkpoint
                        print(f"{preset} {reward}: skipped: {err}", file=sys.stderr)
                        continue
                    rows.append(row)
                    print(json.dumps(row), flush=True)
    head = ("preset", "reward", "variant", "encoder", "net_arch", "batch_size", "update_ratio", "bf16", "overlapped",
            "sac_s_per_1k", "x_env",
            "grad_ms", "env_share", "reward_s_per_1k", "reward_share", "step_ms", "step_ms_none", "step_diff_share")
    print("\n| " + " | ".join(head) + " |\n|" + " --- |" * len(head))
    for r in rows:
        print("| " + " | ".join(str(r[k]) for k in head) + " |")
    load = os.getloadavg()[0]
    print(f"\ntask {args.task}: the plain rgb env steps at {plain_ms:.2f} ms (x_env's yardstick); "
          f"torch threads {torch.get_num_threads()}, load average {load:.2f}")
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    summary = dict(rows=rows, load_average=load, task=args.task, plain_env_ms=plain_ms)
    out.write_text(json.dumps(summary, indent=2) + "\n")
    print(f"written: {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
