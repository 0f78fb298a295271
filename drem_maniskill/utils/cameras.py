"""Camera images of a ManiSkill env, and the one rule that gives cameras their DREM roles.

DREM's model, its sampler and the VICE-RAQ classifier read a *fixed* camera and, where there is
one, a *wrist* camera. On our tasks these are ``fixed_camera`` and ``wrist_camera``; on
ManiSkill's tabletop tasks ``base_camera`` and ``hand_camera`` (``panda_wristcam``).
"""

from __future__ import annotations

from typing import Iterable

# Camera uids that ride on the hand: ours, and ManiSkill's panda_wristcam.
WRIST_CAMERA_UIDS = ("wrist_camera", "hand_camera")
# Our tasks' cameras by role.
OUR_CAMERAS = {"fixed": "fixed_camera", "wrist": "wrist_camera"}


def camera_roles(uids: Iterable[str]) -> dict:
    """Role -> camera uid among ``uids``: ``fixed`` always (when there is any camera), ``wrist`` when there is one.

    ``fixed`` is ``fixed_camera`` if present, else the first camera not on the hand; with only
    hand cameras the first of them plays ``fixed``. ``wrist`` is the first hand camera that is
    not already ``fixed``.
    """
    uids = list(uids)
    fixed = [u for u in uids if u not in WRIST_CAMERA_UIDS]
    wrist = [u for u in uids if u in WRIST_CAMERA_UIDS]
    out = {}
    if OUR_CAMERAS["fixed"] in fixed:
        out["fixed"] = OUR_CAMERAS["fixed"]
    elif fixed or wrist:
        out["fixed"] = (fixed or wrist)[0]
    if wrist and wrist[0] != out.get("fixed"):
        out["wrist"] = wrist[0]
    return out


def env_cameras(env) -> list:
    """Uids of the env's cameras (its sensors that are cameras), in the env's order."""
    return [uid for uid, s in env.unwrapped._sensors.items() if hasattr(s, "camera")]


def camera_images(env, obs, uids: Iterable[str]) -> dict:
    """``{uid: [B, H, W, 3] uint8}`` of ``env``'s current state: from ``obs`` when it holds them, else rendered once.

    Obs modes without rgb (``state``, ``state_dict``, ``none``, depth-only) render the named
    cameras here, once per call; with rgb the images are the observation's own tensors (views,
    not copies).
    """
    uids = tuple(uids)
    data = obs.get("sensor_data") if isinstance(obs, dict) else None
    if data is not None:
        try:
            return {uid: data[uid]["rgb"] for uid in uids}
        except KeyError:
            pass
    u = env.unwrapped
    u.scene.update_render(update_sensors=True, update_human_render_cameras=False)
    out = {}
    for uid in uids:
        u._sensors[uid].capture()
        out[uid] = u._sensors[uid].get_obs(rgb=True, depth=False, position=False, segmentation=False)["rgb"]
    return out
