"""DREM reward checkpoints: one file with the weights and a JSON header, safe to open.

The file is a ``torch.save`` of ``{"format": str, "header": str (JSON), "weights": {name: tensor}}``
and is read with ``torch.load(weights_only=True)``, which unpickles only tensors, strings and
containers: a checkpoint from a stranger cannot run code. The header records what the reward
needs to be used correctly: env id, modalities, camera uids, image size, F/T history length,
render style, the model and training configs, the package version, and the expert's first
and last embeddings ``h(s_0)`` and ``h(s_G)`` are among the weights.

Shipped checkpoints live in ``rewards/<env_id>/`` (``drem.pt``, and ``drem_image.pt`` for the
image-only model): beside the package in a checkout, under ``<prefix>/share/drem-maniskill`` in
a wheel; ``default_checkpoint`` finds them.
"""

from __future__ import annotations

import json
import os
import sys
import tempfile
from pathlib import Path
from typing import Optional

import torch

FORMAT = "drem-maniskill-reward/1"

# rewards/ sits beside the package in a checkout (editable install); a wheel installs it as
# data files under <prefix>/share/drem-maniskill/rewards (pyproject's data-files).
REWARDS_DIRS = (Path(__file__).resolve().parents[2] / "rewards", Path(sys.prefix) / "share" / "drem-maniskill" / "rewards")


class CheckpointError(ValueError):
    """A checkpoint is missing, corrupt or does not fit the env it is used with."""


def save_checkpoint(path: str, header: dict, weights: dict) -> str:
    """Write the checkpoint atomically (temp file + rename); returns the path."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    payload = {"format": FORMAT, "header": json.dumps(header, sort_keys=True), "weights": {k: v.detach().cpu() for k, v in weights.items()}}
    fd, tmp = tempfile.mkstemp(dir=path.parent, suffix=".tmp")
    os.close(fd)
    try:
        torch.save(payload, tmp)
        os.chmod(tmp, 0o644)  # mkstemp makes it private; a checkpoint is meant to be shared
        os.replace(tmp, path)
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)
    return str(path)


def load_checkpoint(path: str) -> tuple[dict, dict]:
    """Read ``(header, weights)``; fails with a clear ``CheckpointError`` on a bad file."""
    path = Path(path)
    if not path.exists():
        raise CheckpointError(
            f"DREM checkpoint {path} not found. Train one with `drem-maniskill train-reward`, or pass "
            "drem_checkpoint=<path> to gym.make"
        )
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
            problems.append(f"it expects an F/T history of {header.get('ft_history')} readings, this env gives {ft_history}")
    if problems:
        raise CheckpointError(
            f"DREM checkpoint {path} does not fit this env: " + "; ".join(problems)
            + ". Use a checkpoint trained on this env (drem-maniskill train-reward) or make the env to match."
        )


def default_checkpoint(env_id: str, image_only: bool = False) -> Path:
    """Path of the shipped checkpoint for ``env_id`` (``rewards/<env_id>/drem.pt``, or ``drem_image.pt``)."""
    name = "drem_image.pt" if image_only else "drem.pt"
    for folder in REWARDS_DIRS:
        if (folder / env_id / name).exists():
            return folder / env_id / name
    return REWARDS_DIRS[0] / env_id / name


def resolve_checkpoint(env_id: str, path: Optional[str], image_only: bool = False) -> Path:
    """The checkpoint to use: ``path`` if given, else the shipped default for ``env_id``."""
    if path:
        return Path(path)
    default = default_checkpoint(env_id, image_only)
    if not default.exists():
        raise CheckpointError(
            f"no DREM checkpoint ships for {env_id} (looked for {default}). Train one with "
            f"`drem-maniskill train-reward` and pass gym.make({env_id!r}, reward_mode='drem', drem_checkpoint=PATH)"
        )
    return default
