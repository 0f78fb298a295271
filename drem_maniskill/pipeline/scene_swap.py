"""Scene-swap negatives (beyond the paper): the demo's robot ahead of its objects, labelled with their depth.

In a progress tree the robot's progress and the objects' go together (and in the paper's chain the objects stay at
the goal at every depth): nothing in it says that the progress is the objects', and a model may read the robot
alone. ``evaluate.scene_swap`` measures that at the expert's end; ``swap_negatives`` teaches against it: for the
demo's states at depths ``k < j`` (steps before its goal) with ``j - k > lag``, the scene with the robot (its joints,
drives and F/T) of depth ``k`` and every other body of depth ``j``, labelled depth ``j``: a scene is as far from the
goal as its objects. They go to training in a negatives file (``pipeline.negatives``; ``train_reward(negatives=...)``);
a row's ``step`` is the robot's depth ``k``. The demo's own states give the objects' progress (the tree's seeds would
not, in the paper's chain). It needs nothing of the task but its state's split into the robot and the rest
(``envs.adapter.compose_scene``).
"""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import numpy as np

from drem_maniskill.envs.adapter import compose_scene
from drem_maniskill.pipeline.negatives import write_negatives
from drem_maniskill.utils.progress import progress_bar


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
