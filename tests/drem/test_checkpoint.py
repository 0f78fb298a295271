"""Reward checkpoints: round trip, safe loading, compatibility checks, the shipped defaults."""

from __future__ import annotations

import pickle
from pathlib import Path

import gymnasium as gym
import pytest
import torch

from drem_maniskill.drem.checkpoint import (
    CheckpointError,
    check_compatible,
    load_checkpoint,
    save_checkpoint,
)
from tests.conftest import SHIPPED_TASKS


def test_checkpoint_round_trip_and_errors(tmp_path):
    path = save_checkpoint(str(tmp_path / "c.pt"), {"env_id": "X-v1"}, {"w": torch.ones(3)})
    header, weights = load_checkpoint(path)
    assert header == {"env_id": "X-v1"} and torch.equal(weights["w"], torch.ones(3))
    with pytest.raises(CheckpointError, match="not found"):
        load_checkpoint(str(tmp_path / "missing.pt"))
    data = open(path, "rb").read()
    (tmp_path / "cut.pt").write_bytes(data[: len(data) // 2])
    with pytest.raises(CheckpointError, match="truncated or corrupt"):
        load_checkpoint(str(tmp_path / "cut.pt"))
    torch.save({"format": "other"}, tmp_path / "other.pt")
    with pytest.raises(CheckpointError, match="not a DREM reward checkpoint"):
        load_checkpoint(str(tmp_path / "other.pt"))


class _Evil:
    def __reduce__(self):
        return (exec, ("import pathlib; pathlib.Path('PWNED').write_text('x')",))


def test_checkpoint_never_executes_code(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    with open(tmp_path / "evil.pt", "wb") as f:
        pickle.dump({"format": "drem-maniskill-reward/1", "header": "{}", "weights": _Evil()}, f)
    with pytest.raises(CheckpointError):
        load_checkpoint(str(tmp_path / "evil.pt"))
    assert not (tmp_path / "PWNED").exists()


def test_compatibility_check_names_every_difference():
    header = dict(env_id="PegInHole-v1", camera_uids=["fixed_camera", "wrist_camera"],
                  modalities=["fixed", "wrist", "ft"], ft_history=8)
    check_compatible(header, "PegInHole-v1", {"fixed_camera": (128, 128), "wrist_camera": (128, 128)}, 8)
    with pytest.raises(CheckpointError) as err:
        check_compatible(header, "USBInsertion-v1", {"fixed_camera": (128, 128)}, 4)
    msg = str(err.value)
    assert "'PegInHole-v1'" in msg and "'USBInsertion-v1'" in msg
    assert "'wrist_camera'" in msg and "history of 8" in msg and "gives 4" in msg
    with pytest.raises(CheckpointError, match="F/T history, which this env does not provide"):
        check_compatible(header, "PegInHole-v1", {"fixed_camera": (1, 1), "wrist_camera": (1, 1)}, None)


@pytest.mark.parametrize("task", SHIPPED_TASKS)
def test_shipped_checkpoints_load_by_default(task):
    env = gym.make(task, obs_mode="state", reward_mode="drem")
    try:
        header = env.unwrapped.drem_reward.header
        assert header["env_id"] == task and header["modalities"] == ["fixed", "wrist", "ft"]
        env.reset(seed=0)
        _, reward, *_ = env.step(torch.zeros(1, 6))
        # At the start of an episode the part is far from the goal: low progress.
        assert reward.shape == (1,) and reward.item() < 0.5
    finally:
        env.close()


def test_resolve_checkpoint_is_the_given_path_or_the_shipped_one(tmp_path, monkeypatch):
    import drem_maniskill.drem.checkpoint as checkpoints
    from drem_maniskill.drem.checkpoint import CheckpointNotFoundError, resolve_checkpoint

    monkeypatch.setattr(checkpoints, "REWARDS_DIRS", (tmp_path / "rewards",))
    shipped = Path(save_checkpoint(str(tmp_path / "rewards" / "X-v1" / "drem.pt"), {"env_id": "X-v1"}, {}))
    assert resolve_checkpoint("X-v1") == shipped
    own = Path(save_checkpoint(str(tmp_path / "own.pt"), {"env_id": "X-v1"}, {}))
    assert resolve_checkpoint("X-v1", str(own)) == own
    # One error for every missing file: what was looked for, and the commands that make one.
    with pytest.raises(CheckpointNotFoundError, match=r"no image-only DREM checkpoint ships for X-v1 .*drem_image\.pt"
                       r".*build-reward --task X-v1.*--model-modalities fixed wrist.*copy it to"):
        resolve_checkpoint("X-v1", image_only=True)
    with pytest.raises(FileNotFoundError, match=r"nowhere\.pt not found\. Build one with `drem-maniskill build-reward"):
        resolve_checkpoint("X-v1", str(tmp_path / "nowhere.pt"))
    with pytest.raises(CheckpointError, match=r"nowhere\.pt not found\. Build one"):
        load_checkpoint(str(tmp_path / "nowhere.pt"))
