"""The rewards SAC can train with, as one table: each entry knows how to make its env and which tasks it fits.

``REWARDS`` maps a reward name to a ``RewardSpec``; adding a reward is one entry here, and the
run loop (``rl.train_policy``) names none of them. A spec makes the env with its reward
(``make``), says whether it fits a task (``supports``), and, for a reward that learns during
the run (VICE-RAQ), builds that learner (``learner``): an object with the ``LearnedReward``
interface, which the run loop updates every ``update_every`` env steps, checkpoints as
``<reward>.pt`` and uses to reward its evaluation env.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Optional, Protocol

import gymnasium as gym

from drem_maniskill.baselines.vice import VICEConfig, VICERewardWrapper
from drem_maniskill.drem import checkpoint as drem_checkpoints
from drem_maniskill.drem.guard import SupportGuard, load_support
from drem_maniskill.drem.wrapper import DREMRewardWrapper
from drem_maniskill.envs import is_insertion_task
from drem_maniskill.experts import collect_goal_examples
from drem_maniskill.utils.episodes import max_episode_steps


class LearnedReward(Protocol):
    """A reward that learns while the policy does: a gymnasium wrapper around the training env."""

    update_every: int  # env steps between ``update`` calls

    def update(self) -> dict:
        """Train on what was visited; returns metrics to log."""

    def state_dict(self) -> dict:
        """Everything to resume (``torch.save``-able)."""

    def load_state_dict(self, state: dict) -> None:
        """Restore a ``state_dict()``."""

    def evaluation_env(self, env: gym.Env) -> gym.Env:
        """``env`` rewarded by this reward, learning nothing from it.

        A learner may also give ``relabel(replay_buffer) -> int``: the run loop calls it after each ``update`` so the
        buffer's transitions are paid by the updated reward (``pipeline.online_rounds``)."""


def env_reward_mode(mode: str) -> Callable:
    """``make`` of a reward that is an env reward mode of ours."""

    def make(task: str, kwargs: dict) -> gym.Env:
        return gym.make(task, reward_mode=mode, **kwargs)

    return make


def drem_make(image_only: bool = False) -> Callable:
    """``make`` of DREM from the shipped checkpoint: the ``drem`` mode on our tasks, the wrapper on ManiSkill's."""

    def make(task: str, kwargs: dict) -> gym.Env:
        kwargs = dict(kwargs)
        path = drem_checkpoints.resolve_checkpoint(task, kwargs.pop("drem_checkpoint", None), image_only=image_only)
        form = kwargs.pop("drem_form", "paper")
        if is_insertion_task(task):
            return gym.make(task, reward_mode="drem", drem_checkpoint=str(path), drem_form=form, **kwargs)
        env = gym.make(task, reward_mode="sparse", **kwargs)
        try:
            return DREMRewardWrapper(env, str(path), form=form)
        except Exception:
            env.close()
            raise

    return make


def _drem_guarded(task: str, kwargs: dict) -> gym.Env:
    """DREM with ``drem.guard.SupportGuard`` (support.json beside the checkpoint): no pay off the tree's support."""
    if kwargs.get("drem_form", "paper") != "paper":
        # The guard scales the reward towards 0, which raises a negative (shifted) reward instead of cutting it.
        raise ValueError("drem-guarded pays only the paper's form of R; use --drem-form paper, or the drem reward")
    env = drem_make(False)(task, kwargs)
    try:
        checkpoint = drem_checkpoints.resolve_checkpoint(task, kwargs.get("drem_checkpoint"))
        return SupportGuard(env, load_support(checkpoint.parent / "support.json"))
    except Exception:
        env.close()
        raise


def _vice_learner(env: gym.Env, task: str, seed: int, options: dict, state: Optional[dict], make_kwargs: dict,
                  run_dir: Optional[Path] = None):
    """VICE-RAQ around the training env; goals from ``state`` when resuming, else from the scripted expert."""
    options = dict(options)
    goal_seeds = int(options.pop("goal_seeds", 10))
    vcfg = VICEConfig(**{"seed": seed, **options})
    if state is not None:
        goals = state["positives"][: state["num_goal_examples"]]
    else:
        # Goal images from the scripted expert in the training env's own look (colours, render style).
        goals = collect_goal_examples(task, seeds=range(goal_seeds), env_kwargs=make_kwargs, cameras=vcfg.cameras,
                                      max_steps=max_episode_steps(task))
    vice = VICERewardWrapper(env, goals, vcfg)
    if state is not None:
        vice.load_state_dict(state)
    return vice


@dataclass(frozen=True)
class RewardSpec:
    """How a reward is made: ``make(task, gym_kwargs) -> env``, the tasks it fits, an optional learner."""

    about: str
    make: Callable[[str, dict], gym.Env]
    stock_tasks: bool = False  # also on ManiSkill's own tasks (they have no F/T, engineered or dense of ours)
    stock_reward_mode: Optional[str] = None  # also on ManiSkill's own tasks that have this reward mode
    checkpoint: bool = False  # reads a DREM checkpoint (RLConfig.reward_checkpoint replaces the shipped one)
    image_only: bool = False  # the checkpoint it reads by default is the image-only one (drem_image.pt)
    learner: Optional[Callable] = None  # (env, task, seed, options, state, gym_kwargs, run_dir) -> LearnedReward

    def supports(self, task: str) -> bool:
        """Whether this reward can be used on ``task``."""
        if is_insertion_task(task) or self.stock_tasks:
            return True
        return self.stock_reward_mode is not None and self.stock_reward_mode in _reward_modes(task)


def _reward_modes(task: str) -> tuple:
    """The reward modes ManiSkill's registered ``task`` supports (none for an unknown id)."""
    from mani_skill.utils.registration import REGISTERED_ENVS

    spec = REGISTERED_ENVS.get(task)
    return tuple(spec.cls.SUPPORTED_REWARD_MODES) if spec is not None else ()


def _drem_spec(about: str, image_only: bool, **kwargs) -> RewardSpec:
    """A DREM reward's spec: the env it makes and the checkpoint it reads agree on ``image_only``."""
    return RewardSpec(about, drem_make(image_only), checkpoint=True, image_only=image_only, **kwargs)


REWARDS: dict[str, RewardSpec] = {
    "sparse": RewardSpec("1 on success, else 0", env_reward_mode("sparse"), stock_tasks=True),
    "dense": RewardSpec("the task's staged dense reward in [0, 1] (ManiSkill style; ManiSkill's own where the task "
                        "has one)", env_reward_mode("normalized_dense"), stock_reward_mode="normalized_dense"),
    "engineered": RewardSpec("-exp(kappa ||x - x_G||), the paper's Engineered", env_reward_mode("engineered")),
    "drem": _drem_spec("DREM, images + F/T, rewards/<task>/drem.pt (image-only on ManiSkill's tasks)", False,
                       stock_tasks=True),
    "drem-guarded": RewardSpec("DREM scaled down where the model cannot reconstruct the state (not in the paper; "
                               "docs/rewards.md)", _drem_guarded, checkpoint=True),
    "drem-image": _drem_spec("DREM on images only, rewards/<task>/drem_image.pt", True),
    # VICE replaces the reward; the env's sparse one is cheap and is kept in info["original_reward"].
    "vice": RewardSpec("VICE-RAQ success classifier on the images", env_reward_mode("sparse"), learner=_vice_learner),
}


def reward_checkpoint(name: str, task: str, given: Optional[str] = None) -> Optional[Path]:
    """The DREM checkpoint reward ``name`` reads on ``task`` (``given``, else the shipped one).

    None if the reward reads none, or if the file is missing (making the env names it).
    """
    spec = reward_spec(name)
    if not spec.checkpoint:
        return None
    if given:  # named as given, so the run's record says what was asked for even before the file exists
        return Path(given)
    try:
        return drem_checkpoints.resolve_checkpoint(task, None, image_only=spec.image_only)
    except drem_checkpoints.CheckpointNotFoundError:
        return None


def reward_spec(name: str) -> RewardSpec:
    """The ``REWARDS`` entry of ``name``, or a ValueError listing the choices."""
    if name not in REWARDS:
        raise ValueError(f"unknown reward {name!r}; choose one of: {', '.join(REWARDS)}")
    return REWARDS[name]


def supported_rewards(task: str) -> list:
    """The reward names that fit ``task``."""
    return [name for name, spec in REWARDS.items() if spec.supports(task)]
