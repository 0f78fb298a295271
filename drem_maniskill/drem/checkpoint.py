"""DREM reward checkpoints: one file with the weights and a JSON header, safe to open.

The file is a ``torch.save`` of ``{"format": str, "header": str (JSON), "weights": {name: tensor}}``
and is read with ``torch.load(weights_only=True)``, which unpickles only tensors, strings and
containers: a checkpoint from a stranger cannot run code. The header records what the reward
needs to be used correctly: env id, modalities, camera uids, image size, F/T history length,
render style, the model and training configs, the package version, and the expert's first
and last embeddings ``h(s_0)`` and ``h(s_G)`` are among the weights.

Shipped checkpoints live in ``rewards/<env_id>/`` (``drem.pt``, and ``drem_image.pt`` for the
image-only model): beside the package in a checkout, under ``<prefix>/share/drem-maniskill`` in
a wheel; ``resolve_checkpoint`` finds them.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Optional

import torch

from drem_maniskill.utils.atomic import atomic_path

FORMAT = "drem-maniskill-reward/1"

# rewards/ sits beside the package in a checkout (editable install); a wheel installs it as
# data files under <prefix>/share/drem-maniskill/rewards (pyproject's data-files).
REWARDS_DIRS = (Path(__file__).resolve().parents[2] / "rewards",
                Path(sys.prefix) / "share" / "drem-maniskill" / "rewards")


class CheckpointError(ValueError):
    """A checkpoint is missing, corrupt or does not fit the env it is used with."""


def save_checkpoint(path: str, header: dict, weights: dict) -> str:
    """Write the checkpoint atomically (``utils.atomic``); returns the path."""
    payload = {"format": FORMAT, "header": json.dumps(header, sort_keys=True),
               "weights": {k: v.detach().cpu() for k, v in weights.items()}}
    with atomic_path(path) as tmp:
        torch.save(payload, tmp)
    return str(Path(path))


def load_checkpoint(path: str) -> tuple[dict, dict]:
    """Read ``(header, weights)``; fails with a clear ``CheckpointError`` on a bad file."""
    path = Path(path)
    if not path.exists():
        raise missing_checkpoint(path)
    try:
        payload = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as err:  # torch raises several types for truncated or foreign files
        raise CheckpointError(
            f"{path} is not a readable DREM checkpoint ({type(err).__name__}: {str(err)[:200]}). "
            "It may be truncated or corrupt; re-download it or retrain with `drem-maniskill train-reward`."
        ) from err
    if not isinstance(payload, dict) or payload.get("format") != FORMAT:
        found = payload.get("format") if isinstance(payload, dict) else type(payload).__name__
        raise CheckpointError(f"{path} is not a DREM reward checkpoint (format {found!r}, expected {FORMAT!r})")
    try:
        header = json.loads(payload["header"])
    except (KeyError, json.JSONDecodeError) as err:
        raise CheckpointError(f"{path} has a corrupt header: {err}") from err
    return header, payload["weights"]


def check_compatible(header: dict, env_id: str, cameras: dict, ft_history: int | None, path: str = "") -> None:
    """Raise ``CheckpointError`` naming every difference between a checkpoint and an env.

    ``cameras`` maps camera uid -> (height, width) for the env; ``ft_history`` is the env's F/T
    history length or None when the env has no F/T sensor.
    """
    problems = []
    if header.get("env_id") != env_id:
        problems.append(f"it was trained on {header.get('env_id')!r}, this env is {env_id!r}")
    for uid in header.get("camera_uids", []):
        if uid not in cameras:
            problems.append(f"it needs camera {uid!r}, which this env lacks (has {sorted(cameras)})")
    if "ft" in header.get("modalities", []):
        if ft_history is None:
            problems.append("it uses the wrist F/T history, which this env does not provide")
        elif ft_history != header.get("ft_history"):
            problems.append(f"it expects an F/T history of {header.get('ft_history')} readings, "
                            f"this env gives {ft_history}")
    if problems:
        raise CheckpointError(
            f"DREM checkpoint {path} does not fit this env: " + "; ".join(problems)
            + ". Use a checkpoint trained on this env (drem-maniskill train-reward) or make the env to match."
        )


def default_checkpoint(env_id: str, image_only: bool = False) -> Path:
    """Where the shipped checkpoint of ``env_id`` is, or would be (``rewards/<env_id>/drem.pt`` or ``drem_image.pt``).

    It does not check that the file exists; ``resolve_checkpoint`` does, and is what code that loads one calls.
    """
    name = "drem_image.pt" if image_only else "drem.pt"
    for folder in REWARDS_DIRS:
        if (folder / env_id / name).exists():
            return folder / env_id / name
    return REWARDS_DIRS[0] / env_id / name


def resolve_checkpoint(env_id: str, path: Optional[str] = None, image_only: bool = False) -> Path:
    """The checkpoint to use for ``env_id``: ``path`` if given, else the shipped one; a clear error if it is missing.

    ``image_only`` picks the image-only model (``drem_image.pt``) as the shipped default.
    """
    resolved = Path(path) if path else default_checkpoint(env_id, image_only)
    if not resolved.exists():
        raise missing_checkpoint(resolved, env_id, given=bool(path), image_only=image_only)
    return resolved


class CheckpointNotFoundError(CheckpointError, FileNotFoundError):
    """A checkpoint file that does not exist (a ``FileNotFoundError`` too)."""


def missing_checkpoint(path, env_id: Optional[str] = None, given: bool = True,
                       image_only: bool = False) -> CheckpointNotFoundError:
    """The one error for a DREM checkpoint that is not there: what was looked for and how to make or name one."""
    kind = "image-only DREM checkpoint" if image_only else "DREM checkpoint"
    if given or env_id is None:
        what = f"{kind} {path} not found"
    else:
        what = f"no {kind} ships for {env_id} (looked for {path})"
    task = env_id or "<task>"
    modalities = " --model-modalities fixed wrist" if image_only else ""
    return CheckpointNotFoundError(
        f"{what}. Build one with `drem-maniskill build-reward --task {task}`, or train one with "
        f"`drem-maniskill train-reward --dataset TREE.h5 --out DIR{modalities}`; then pass its path "
        f"(gym.make({task!r}, reward_mode='drem', drem_checkpoint=PATH), or train-policy --reward-checkpoint PATH)"
        + ("" if given else f" or copy it to {path}")
    )
