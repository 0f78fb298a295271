"""Scene-swap negatives: the robot ahead of the task's objects (beyond the paper).

In a progress tree the robot's progress and the objects' go together (and in the paper's chain the objects stay at
the goal at every depth): nothing in it says that the progress is the objects', and a model may read the robot
alone (the examination's scene swap, ``pipeline.examine.scene_swap``, measures it). A policy then finds the robot's
end pose without the task done.

These negatives say it: for the demo's states at depths ``k < j`` (steps before its goal) with ``j - k > lag``, the
scene with the robot (its joints, drives and F/T) of depth ``k`` and every other body of depth ``j``, labelled depth
``j``: a scene is as far from the goal as its objects. They need nothing of the task but its state's split into the
robot and the rest, and go to training as ``pipeline.policy_rounds``' negatives files do
(``train_reward(negatives=...)``). The paper's chain leaves the objects at the goal at every depth of the tree, so
the demo's own states, not the tree's seeds, give the objects' progress.
"""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import numpy as np

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
    from drem_maniskill.pipeline.examine import compose_scene
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
            rows.append((inputs, float("nan"), expert.episode_seed, k))
    finally:
        sampler.env.close()
    cameras = list(rows[0][0]) if rows else []
    write_negatives(Path(out), rows, np.array([j for _, j in pairs]), [c for c in cameras if c != "ft"],
                    adapter.has_ft)
    return dict(episode=episode, negatives=len(rows), lag=lag, demo_steps=last)
