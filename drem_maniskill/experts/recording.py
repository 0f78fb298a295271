"""Record scripted-expert demonstrations in ManiSkill's trajectory format (RecordEpisode).

The files are what ManiSkill's ``RecordEpisode`` writes: ``<name>.h5`` (per episode
``traj_<i>`` with ``obs``, ``actions``, ``env_states``, ``success``, ...) and ``<name>.json``
(env id, env kwargs, episode seeds). A user's own demo in the same format can replace it.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Optional, Sequence

import gymnasium as gym

from mani_skill.utils.wrappers.record import RecordEpisode

from drem_maniskill.experts.control import ee_control_kwargs
from drem_maniskill.envs import InsertionEnv
from drem_maniskill.experts.policies import get_policy
from drem_maniskill.experts.scripted import ExpertPolicy
from drem_maniskill.experts.rollout import rollout
from drem_maniskill.utils.atomic import write_json
from drem_maniskill.utils.episodes import episode_horizon
from drem_maniskill.utils.progress import progress_bar


@dataclass
class RecordResult:
    """What ``record_expert`` wrote and how the episodes went."""

    h5_path: str
    json_path: str
    seeds: list = field(default_factory=list)
    success: list = field(default_factory=list)
    lengths: list = field(default_factory=list)

    @property
    def success_rate(self) -> float:
        """Fraction of recorded episodes that ended in success."""
        return sum(self.success) / max(len(self.success), 1)


def record_expert(
    env_id: str,
    out_dir: str,
    seeds: Sequence[int] = (0,),
    obs_mode: str = "rgb",
    name: str = "expert",
    policy="expert",
    save_video: bool = False,
    max_steps: Optional[int] = None,
    env_kwargs: Optional[dict] = None,
    descent_step: Optional[float] = None,
    descend_from: Optional[float] = None,
) -> RecordResult:
    """Roll out a scripted policy (a name, or a callable ``obs -> action``) on ``seeds``; save with ``RecordEpisode``.

    ``descent_step``: our tasks' ``expert`` only, metres per step once inside the hole (default 0.005);
    ``descend_from``: its height above the opening where the slow descent starts (``ExpertPolicy``).
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    env_kwargs = ee_control_kwargs(env_id, env_kwargs)
    env = gym.make(env_id, obs_mode=obs_mode, render_mode="rgb_array" if save_video else None, **env_kwargs)
    # info_on_video crashes with numpy 2.4 in ManiSkill 3.0.1; keep it off.
    env = RecordEpisode(
        env, str(out), trajectory_name=name, save_video=save_video, info_on_video=False,
        save_on_reset=False, record_env_state=True, video_fps=5,
    )
    first = int(seeds[0]) if len(seeds) else 0
    try:
        if descent_step is None and descend_from is None:
            pi = policy if callable(policy) else get_policy(policy, env, seed=first)
        elif policy == "expert" and isinstance(env.unwrapped, InsertionEnv):
            pi = ExpertPolicy(env, seed=first, descent_step=descent_step, descend_from=descend_from)
        else:
            raise ValueError(f"descent_step and descend_from set the expert of our insertion tasks, "
                             f"not {policy!r} on {env_id}")
    except Exception:
        env.close()
        raise
    horizon = max_steps or episode_horizon(env)
    result = RecordResult(h5_path=str(out / f"{name}.h5"), json_path=str(out / f"{name}.json"))
    try:
        desc = f"record {getattr(policy, '__name__', policy)} on {env_id}"
        for seed in progress_bar(list(seeds), desc=desc, unit="episode"):
            ep = rollout(env, pi, int(seed), horizon)
            env.flush_trajectory()
            if save_video:
                env.flush_video()
            result.seeds.append(int(seed))
            result.success.append(bool(ep.info["success"].any()))
            result.lengths.append(ep.length)
    finally:
        env.close()
    write_json(out / f"{name}.summary.json", {**asdict(result), "success_rate": result.success_rate})
    return result
