"""Which PhysX contact setting makes backward sampling see what an episode sees: PCM on or off.

The sampler restores a state and applies one action; at run time the same step follows the
step before it. With PhysX's persistent contact manifolds (``enable_pcm``, ManiSkill's default)
a restored state in contact carries the contact cache of whatever ran before the restore (the
sibling sampled just before), which no state holds; without them there is no cache at all.

For contact-rich episodes (Align Success and Search Fail, PCM on as at run time) this replays
every step in contact from its restored state, after an unrelated step (a random action from
the same state, as a sibling would be), once in an env with PCM on and once with PCM off, and
compares the result with the episode's own next state: the tip's position and the wrist force.
It also replays each step twice with PCM on after different siblings: how much the result
depends on the sibling. Writes a JSON of the numbers.

Run: .venv/bin/python experiments/measure_pcm.py [--seeds 4] [--out outputs/pcm/pcm.json]
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import gymnasium as gym
import numpy as np
import torch

from drem_maniskill.envs import TASKS
from drem_maniskill.experts import get_policy
from drem_maniskill.experts.scripted import CONTACT_FORCE

PCM_OFF = dict(sim_config=dict(scene_config=dict(enable_pcm=False)))


def outcome(env) -> np.ndarray:
    """Tip position in the socket frame (mm) and the newest wrist force (N), one row."""
    u = env.unwrapped
    return np.concatenate([u.tip_pose_in_socket().p[0].cpu().numpy() * 1000, u.ft.buffer[0, -1, :3].cpu().numpy()])


def replay(env, state: dict, action: torch.Tensor, sibling: torch.Tensor) -> np.ndarray:
    """Restore ``state``, run ``sibling`` from it, restore again, run ``action``: the sampler's order."""
    u = env.unwrapped
    u.set_state_dict(state)
    env.step(sibling)
    u.set_state_dict(state)
    env.step(action)
    return outcome(env)


def measure(task: str, seeds, policies=("align_success", "search_fail")) -> dict:
    """Errors of the PCM-on and PCM-off replays against the episode, over every contact step of the episodes."""
    truth_env = gym.make(task, obs_mode="state_dict")
    on_env = gym.make(task, obs_mode="state_dict")
    off_env = gym.make(task, obs_mode="state_dict", **PCM_OFF)
    gen = torch.Generator().manual_seed(0)
    rows = {"on": [], "off": [], "on_vs_on": []}
    try:
        for env in (on_env, off_env):
            env.reset(seed=0)
        for policy_name in policies:
            for seed in seeds:
                policy = get_policy(policy_name, truth_env, seed=seed)
                obs, _ = truth_env.reset(seed=seed)
                for _ in range(50):
                    state = truth_env.unwrapped.get_state_dict()
                    action = policy(obs)
                    obs, _, _, truncated, _ = truth_env.step(action)
                    truth = outcome(truth_env)
                    if np.abs(truth[3:]).max() > CONTACT_FORCE:
                        siblings = [torch.rand(1, 6, generator=gen) * 2 - 1 for _ in range(2)]
                        on = replay(on_env, state, action, siblings[0])
                        rows["on"].append(on - truth)
                        rows["off"].append(replay(off_env, state, action, siblings[0]) - truth)
                        rows["on_vs_on"].append(replay(on_env, state, action, siblings[1]) - on)
                    if bool(truncated.any()):
                        break
    finally:
        for env in (truth_env, on_env, off_env):
            env.close()

    def summary(diffs):
        d = np.asarray(diffs)
        pos, force = np.linalg.norm(d[:, :3], axis=1), np.linalg.norm(d[:, 3:], axis=1)
        return dict(steps=len(d), tip_error_mm_median=float(np.median(pos)),
                    tip_error_mm_p90=float(np.quantile(pos, 0.9)),
                    force_error_n_median=float(np.median(force)), force_error_n_p90=float(np.quantile(force, 0.9)))

    return {k: summary(v) for k, v in rows.items() if v}


def main() -> None:
    """Measure every task; print and write the JSON."""
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--seeds", type=int, default=4)
    parser.add_argument("--out", default="outputs/pcm/pcm.json")
    args = parser.parse_args()
    result = {task: measure(task, range(args.seeds)) for task in TASKS}
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(result, indent=2) + "\n")
    print(json.dumps(result, indent=2))


if __name__ == "__main__":
    main()
