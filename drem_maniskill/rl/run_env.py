"""The env of a SAC run: the task, with the reward of ``rewards.REWARDS``, seen through the policy's observation."""

from __future__ import annotations

from typing import Optional

import gymnasium as gym

from drem_maniskill.envs import check_env_id, is_insertion_task
from drem_maniskill.experts import ee_control_kwargs
from drem_maniskill.rl.observation import PolicyObservation, state_parts, task_state_parts
from drem_maniskill.rl.rewards import reward_spec, supported_rewards
from drem_maniskill.rl.vec_env import ManiSkillDictVecEnv, SubprocDictVecEnv
from drem_maniskill.utils.cameras import camera_roles, env_cameras
from drem_maniskill.utils.episodes import max_episode_steps


def make_env(config, learned_state: Optional[dict] = None, learned=None, for_eval: bool = False):
    """``(env, learned_reward_or_None)`` of an ``RLConfig``: the policy's obs (see below), the named reward.

    With cameras (presets ``light``, ``paper``) the env's obs mode is ``rgb``, rendered at 128 px;
    without (``state``) it is ``state_dict`` and nothing is rendered for the policy (a reward that
    reads images, DREM or VICE-RAQ, renders its own cameras).

    A learned reward (VICE-RAQ) wraps the training env and is returned beside it, restored from
    ``learned_state`` when resuming; an evaluation env (``for_eval``, one env) is rewarded by the
    training env's ``learned`` reward, which learns nothing from it. On ManiSkill's own tasks the
    policy sees the task's two cameras in the roles of ours (``base_camera``, ``hand_camera``) and
    no F/T; control is ``pd_ee_delta_pose``, as for the expert a DREM checkpoint was made from.
    """
    task = check_env_id(config.task)
    spec = reward_spec(config.reward)
    if not spec.supports(task):
        raise ValueError(f"on ManiSkill's own {task} the rewards are {supported_rewards(task)} "
                         f"(drem: rewards/{task}/drem.pt), not {config.reward!r}")
    if config.reward_checkpoint and not spec.checkpoint:
        raise ValueError(f"reward_checkpoint (--reward-checkpoint) is for the DREM rewards, not {config.reward!r}")
    obs_mode = "rgb" if config.uses_images else "state_dict"
    kwargs = dict(obs_mode=obs_mode, sim_backend=config.sim_backend, **ee_control_kwargs(task, config.env_kwargs))
    make_kwargs = dict(kwargs, num_envs=1 if for_eval else config.num_envs)
    if config.reward_checkpoint:
        make_kwargs["drem_checkpoint"] = config.reward_checkpoint
    if spec.checkpoint:
        make_kwargs["drem_form"] = config.drem_form_used
    elif config.drem_form not in (None, "paper"):
        raise ValueError(f"drem_form (--drem-form) is for the DREM rewards, not {config.reward!r}")
    env = spec.make(task, make_kwargs)
    if spec.learner is not None:
        if for_eval:
            env = learned.evaluation_env(env)
        else:
            env = learned = spec.learner(env, task, config.seed, config.reward_kwargs, learned_state, kwargs,
                                         run_dir=config.run_dir)
    if config.action_scale != 1.0:
        # The policy's full range becomes a fraction of the controller's: finer steps for the same squashed output.
        scale = float(config.action_scale)
        env = gym.wrappers.TransformAction(env, lambda a: a * scale, env.action_space)
    if not config.uses_images:
        cameras = ()
    else:
        cameras = config.cameras if is_insertion_task(task) else tuple(camera_roles(env_cameras(env)).values())
    keys = state_parts(config.policy_qvel, config.policy_privileged and is_insertion_task(task))
    if config.policy_privileged and not is_insertion_task(task) and obs_mode == "state_dict":
        # ManiSkill's own tasks: their object and goal poses, as ManiSkill's state observation has them.
        keys += task_state_parts(env.unwrapped.single_observation_space["extra"])
    return PolicyObservation(env, config.image_size, cameras, ft=config.uses_ft, state=config.policy_state,
                             state_keys=keys), learned


def make_eval_env(config, learned=None) -> gym.Env:
    """The one-env evaluation env of a run (rewarded by ``learned`` where the reward learns)."""
    return make_env(config, learned=learned, for_eval=True)[0]


def make_local_vec_env(config, learned_state: Optional[dict] = None):
    """``(venv, learned_or_None)``: ``make_env``'s training env as SB3's ``ManiSkillDictVecEnv``, in this process."""
    env, learned = make_env(config, learned_state=learned_state)
    return ManiSkillDictVecEnv(env, max_episode_steps(config.task), config.terminate_on_success), learned


def make_vec_env(config, learned_state: Optional[dict] = None):
    """``(venv, learned_or_None)``: the run's training env for SB3, in a child process (``SubprocDictVecEnv``)
    where ``config.overlap_env_used``, else ``make_local_vec_env``'s."""
    if config.overlap_env_used:
        return SubprocDictVecEnv(make_local_vec_env, config), None
    return make_local_vec_env(config, learned_state)
