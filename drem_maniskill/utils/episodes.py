"""Episode lengths of ManiSkill envs, wherever the limit is kept."""

from __future__ import annotations


def max_episode_steps(env_id: str, default: int = 50) -> int:
    """Episode length of a registered id: ManiSkill's registry, else gymnasium's spec, else ``default``."""
    import gymnasium as gym
    from mani_skill.utils.registration import REGISTERED_ENVS

    env_id = env_id.split(":")[-1]
    spec = REGISTERED_ENVS.get(env_id)
    if spec is not None and spec.max_episode_steps:
        return int(spec.max_episode_steps)
    try:
        gspec = gym.spec(env_id)
    except gym.error.Error:
        return default
    return int(gspec.max_episode_steps or gspec.kwargs.get("max_episode_steps") or default)


def episode_horizon(env) -> int:
    """The env's episode length: its ManiSkill ``TimeLimitWrapper``'s, else the registry's, else 50.

    ``env.spec.max_episode_steps`` is None for every ``gym.make`` of a ManiSkill id (the limit
    lives in ManiSkill's own wrapper), so it cannot be used.
    """
    e = env
    while e is not None:
        limit = getattr(e, "_max_episode_steps", None)
        if limit:
            return int(limit)
        e = getattr(e, "env", None)
    spec = env.unwrapped.spec
    return max_episode_steps(spec.id) if spec is not None else 50
