"""What the scripted policies ask of an env's controller: ``pd_ee_delta_pose``, on our tasks and ManiSkill's."""

from __future__ import annotations

from drem_maniskill.envs import is_insertion_task


def ee_control_kwargs(env_id: str, env_kwargs: dict | None = None) -> dict:
    """``env_kwargs`` with ``control_mode='pd_ee_delta_pose'`` on ManiSkill's own tasks unless given.

    Their default is joint deltas; the stock experts, the sampler and the examination command
    end-effector deltas, as on our tasks (whose default that already is).
    """
    kwargs = dict(env_kwargs or {})
    if not is_insertion_task(env_id):
        kwargs.setdefault("control_mode", "pd_ee_delta_pose")
    return kwargs


def require_ee_control(env, who: str = "scripted policies") -> None:
    """ValueError naming the fix unless ``env`` runs ManiSkill's ``pd_ee_delta_pose`` controller."""
    mode = env.unwrapped.control_mode
    if mode != "pd_ee_delta_pose":
        raise ValueError(f"{who} command end-effector deltas; make the env with control_mode='pd_ee_delta_pose' "
                         f"(got {mode!r})")
