"""The scene swap: does a reward read the task's objects or the robot? A measure and negatives (beyond the paper).

In a progress tree the robot's progress and the objects' go together (and in the paper's chain the objects stay at
the goal at every depth): nothing in it says that the progress is the objects', and a model may read the robot
alone. A policy then finds the robot's end pose without the task done.

* **The measure** (``scene_swap``, in every examination): at the expert's end, the reward with the robot left there
  and every other body put back where the episode started, and the other way round; ``swap_ratios`` sets each over
  the end's reward (``robot_only_over_expert``: near 1, the reward reads the robot).
* **Negatives** (``swap_negatives``): for the demo's states at depths ``k < j`` (steps before its goal) with
  ``j - k > lag``, the scene with the robot (its joints, drives and F/T) of depth ``k`` and every other body of
  depth ``j``, labelled depth ``j``: a scene is as far from the goal as its objects. They go to training as
  ``pipeline.policy_rounds``' negatives files do (``train_reward(negatives=...)``); a row's ``step`` is the robot's
  depth ``k``. The demo's own states give the objects' progress (the tree's seeds would not, in the paper's chain).

Both need nothing of the task but its state's split into the robot and the rest (``envs.adapter.compose_scene``).
"""

from __future__ import annotations

from pathlib import Path
from typing import Optional, Sequence

import numpy as np

from drem_maniskill.envs.adapter import adapter_for, compose_scene
from drem_maniskill.utils.progress import progress_bar


def scene_swap(env, seed: int) -> dict:
    """``R`` at the expert's end, with the robot there and the other bodies back where the episode started
    (``robot_at_end``), and the other way round (``objects_at_end``).

    Call it right after the expert's episode of ``seed``: it reads the end state and resets ``env`` to ``seed``. A
    reward that pays ``robot_at_end`` about what it pays the end reads the robot, not the task.
    """
    u = env.unwrapped
    adapter = adapter_for(env)
    reward = getattr(env, "reward_model", None) or u.drem_reward
    robot = u.agent.robot.name
    end = adapter.get_state()
    env.reset(seed=seed)
    start = adapter.get_state()

    def paid(state: dict) -> float:
        adapter.set_state(state)
        return float(reward.reward(env, None)[0])

    return dict(end=paid(end), robot_at_end=paid(compose_scene(end, start, robot)),
                objects_at_end=paid(compose_scene(start, end, robot)))


def swap_ratios(swaps: Sequence[dict]) -> dict:
    """``robot_only_over_expert`` and ``objects_only_over_expert``: the mean ``R`` of ``scene_swap``'s two swapped
    scenes over its mean at the expert's end (None without episodes)."""
    if not swaps:
        return dict(robot_only_over_expert=None, objects_only_over_expert=None)
    end = float(np.mean([w["end"] for w in swaps]))
    return {f"{name}_over_expert": float(np.mean([w[key] for w in swaps])) / end if end else None
            for name, key in (("robot_only", "robot_at_end"), ("objects_only", "objects_at_end"))}


def swap_pairs(depths, lag: int, max_pairs: Optional[int] = None) -> list:
    """The ``(robot depth k, objects depth j)`` pairs with ``j - k > lag``, at most ``max_pairs`` spread evenly."""
    pairs = [(k, j) for k in sorted(depths) for j in sorted(depths) if j - k > lag]
    if max_pairs is not None and len(pairs) > max_pairs:
        pairs = [pairs[i] for i in np.linspace(0, len(pairs) - 1, max_pairs).round().astype(int)]
    return pairs


def swap_negatives(expert_path: str, out: str, episode: int = 0, lag: int = 4, max_pairs: Optional[int] = 500,
                   progress: bool = True) -> dict:
    """Write ``out`` (a negatives file) with the scene swaps of episode ``episode`` of the demo ``expert_path``;
    returns its counts. ``lag``: the least depth gap (the triplet loss's ``eps``: closer scenes are neighbours
    anyway)."""
    from drem_maniskill.pipeline.policy_rounds import write_negatives
    from drem_maniskill.pipeline.tree.child_sampler import ChildSampler
    from drem_maniskill.pipeline.tree.expert import load_expert
    from drem_maniskill.utils.state import broadcast_state, state_at

    expert = load_expert(expert_path, episode)
    last = expert.length - 1
    pairs = swap_pairs(range(last + 1), lag, max_pairs)
    if not pairs:
        raise ValueError(f"episode {episode} of {expert_path} has {expert.length} states, none more than {lag} "
                         "steps apart; a scene swap needs a longer demo")
    sampler = ChildSampler(expert.env_id, expert.env_kwargs, expert.episode_seed)
    adapter = sampler.adapter
    robot = sampler.unwrapped.agent.robot.name
    rows = []
    try:
        dicts = {d: broadcast_state(state_at(expert.states, last - d), sampler.n) for d in range(last + 1)}
        for k, j in progress_bar(pairs, desc="scene-swap negatives", enabled=progress):
            adapter.set_state(compose_scene(dicts[k], dicts[j], robot))
            inputs = {m: v[:1].cpu().clone() for m, v in adapter.images(None).items()}
            if adapter.has_ft:
                inputs["ft"] = adapter.ft()[:1].cpu().clone()
            inputs["poses"] = adapter.poses()[:1].cpu().clone()
            rows.append((inputs, float("nan"), expert.episode_seed, k))
    finally:
        sampler.env.close()
    write_negatives(Path(out), rows, np.array([j for _, j in pairs]), list(adapter.camera_map), adapter.has_ft)
    return dict(episode=episode, negatives=len(rows), lag=lag, demo_steps=last)
