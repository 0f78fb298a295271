"""record_expert: ManiSkill's RecordEpisode files, with video."""

from __future__ import annotations

import json

import h5py
import numpy as np
import pytest

import drem_maniskill  # noqa: F401


def test_record_expert_on_a_stock_task_with_video(tmp_path):
    """record-expert on PlugCharger-v1: a successful observation + state demo and a video.

    ``RecordEpisode(info_on_video=True)`` crashes with numpy 2.4 in ManiSkill 3.0.1; the recorder
    keeps it off, so a video of a stock task is written all the same.
    """
    from drem_maniskill.experts.recording import record_expert

    rec = record_expert("PlugCharger-v1", str(tmp_path), seeds=[0], save_video=True)
    assert rec.success == [True] and rec.lengths[0] < 100
    meta = json.loads((tmp_path / "expert.json").read_text())
    assert meta["env_info"]["env_id"] == "PlugCharger-v1"
    assert meta["env_info"]["env_kwargs"]["control_mode"] == "pd_ee_delta_pose"
    with h5py.File(rec.h5_path, "r") as f:
        traj = f["traj_0"]
        steps = traj["actions"].shape[0]
        assert steps == rec.lengths[0] and traj["actions"].shape[1] == 7
        for cam in ("base_camera", "hand_camera"):
            rgb = traj["obs"]["sensor_data"][cam]["rgb"]
            assert rgb.shape == (steps + 1, 128, 128, 3) and rgb.dtype == np.uint8
        assert "env_states" in traj and traj["success"][-1]
    assert sorted(p.name for p in tmp_path.glob("*.mp4")) == ["0.mp4"]


@pytest.mark.parametrize("task, fast, slow, gain", [
    # The approach is the same; the peg's last 34 mm take 17 steps at 2 mm instead of 7 at 5 mm.
    ("PegInHole-v1", 0.005, 0.002, 5),
    # Below the entry's 2 mm a step the first 6 mm slow down too: USB's 9.6 mm to success take about
    # 5 steps at 2 mm and 10 or more at 1 mm; had the entry stayed at 2 mm, 1 mm would add 2-3 steps.
    ("USBInsertion-v1", 0.002, 0.001, 6),
])
def test_a_slower_expert_descent_records_more_steps_inside_the_hole(tmp_path, task, fast, slow, gain):
    """``descent_step`` (record-expert --descent-step): the same seed, more steps below the opening, still a success."""
    from drem_maniskill.experts.recording import record_expert

    lengths = {}
    for step in (fast, slow):
        rec = record_expert(task, str(tmp_path / str(step)), seeds=[1000], obs_mode="state_dict", descent_step=step)
        assert rec.success == [True]
        lengths[step] = rec.lengths[0]
    assert lengths[slow] >= lengths[fast] + gain, lengths


def test_an_expert_that_descends_from_the_pre_insertion_point_hovers_fewer_steps_and_enters_the_same():
    """``descend_from`` (record-expert --descend-from): the demo spends fewer steps above the opening, the same near it.

    The expert aligns about 2 cm above the opening on seed 1000; by default it crawls down from there
    at the entry's 2 mm a step (12 steps above the opening), with 6 mm it moves to the pre-insertion
    point at its approach speed first. The last 6 mm above the opening and the insertion stay fine.
    """
    import gymnasium as gym

    from drem_maniskill.experts.rollout import rollout
    from drem_maniskill.experts.scripted import ExpertPolicy

    env = gym.make("USBInsertion-v1", obs_mode="state_dict", control_mode="pd_ee_delta_pose")
    try:
        heights = {}
        for descend_from in (None, 0.006):
            ep = rollout(env, ExpertPolicy(env, seed=1000, descend_from=descend_from), 1000,
                         measure=lambda e, *_: {"z": float(e.unwrapped.tip_pose_in_socket().p[0, 2])})
            assert ep.success, descend_from
            heights[descend_from] = np.asarray(ep.measures["z"])
    finally:
        env.close()
    above = {k: int((z > 0).sum()) for k, z in heights.items()}
    near = {k: int(((z > 0) & (z < 0.0065)).sum()) for k, z in heights.items()}
    inside = {k: int((z < 0).sum()) for k, z in heights.items()}
    assert above[0.006] <= above[None] - 4, above
    assert abs(near[0.006] - near[None]) <= 1 and near[0.006] >= 3, near
    assert inside[0.006] == inside[None], inside


def test_descent_step_is_refused_where_there_is_no_insertion_expert(tmp_path):
    from drem_maniskill.experts.recording import record_expert

    with pytest.raises(ValueError, match="descent_step"):
        record_expert("PlugCharger-v1", str(tmp_path), seeds=[0], descent_step=0.002)
    with pytest.raises(ValueError, match="metres per step"):
        record_expert("PegInHole-v1", str(tmp_path), seeds=[0], descent_step=0.05)
    with pytest.raises(ValueError, match="descend_from"):
        record_expert("PlugCharger-v1", str(tmp_path), seeds=[0], descend_from=0.006)
    with pytest.raises(ValueError, match="above the socket's top face"):
        record_expert("PegInHole-v1", str(tmp_path), seeds=[0], descend_from=-0.01)
