"""The scene swap (beyond the paper, in every examination): does a reward read the task's objects or the robot?

In a progress tree the robot's progress and the objects' go together: nothing in it says that the progress is the
objects', and a model may read the robot alone. A policy then finds the robot's end pose without the task done.
At the expert's end, ``scene_swap`` reads the reward with the robot left there and every other body put back where
the episode started, and the other way round; ``swap_ratios`` sets each over the end's reward
(``robot_only_over_expert``: near 1, the reward reads the robot). It needs nothing of the task but its state's split
into the robot and the rest (``envs.adapter.compose_scene``). The same swap, made into training negatives, is
``pipeline.scene_swap``.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

from drem_maniskill.envs.adapter import adapter_for, compose_scene


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
