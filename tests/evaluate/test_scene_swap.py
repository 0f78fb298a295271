"""The scene swap: at the expert's end, the reward with the robot there and the objects back, and the other way."""

import pytest


def test_swap_ratios_are_the_swapped_scenes_mean_over_the_ends_mean():
    from drem_maniskill.evaluate.scene_swap import swap_ratios

    rows = [dict(end=1.0, robot_at_end=0.9, objects_at_end=0.1), dict(end=0.6, robot_at_end=0.7, objects_at_end=0.3)]
    assert swap_ratios(rows) == pytest.approx(dict(robot_only_over_expert=1.0, objects_only_over_expert=0.25))
    assert swap_ratios([]) == dict(robot_only_over_expert=None, objects_only_over_expert=None)


@pytest.mark.slow
def test_scene_swap_pays_the_experts_end_as_the_episode_did_and_moves_only_what_it_says(tmp_path):
    """On PushCube-v1: the end is paid what the episode's last step was, and the swapped scenes put the cube back
    (robot at the end) or the hand back (cube at the end)."""
    import torch

    from drem_maniskill.evaluate.examine import _make_env, examination_episode
    from drem_maniskill.evaluate.scene_swap import scene_swap
    from tests.conftest import tiny_checkpoint

    checkpoint = tiny_checkpoint(tmp_path / "drem.pt", "PushCube-v1", ("fixed",), ("base_camera",))
    env = _make_env("PushCube-v1", checkpoint, None)
    u = env.unwrapped
    try:
        env.reset(seed=0)
        cube_start, tcp_start = u.obj.pose.p.clone(), u.agent.tcp.pose.p.clone()
        ep = examination_episode(env, "expert", 0)
        assert ep["success"]
        cube_end, tcp_end = u.obj.pose.p.clone(), u.agent.tcp.pose.p.clone()
        assert torch.linalg.norm(cube_end - cube_start) > 0.05 and torch.linalg.norm(tcp_end - tcp_start) > 0.05
        swap = scene_swap(env, 0)
        assert swap["end"] == pytest.approx(ep["rewards"][-1], abs=1e-5)
        assert len({round(swap[k], 4) for k in ("end", "robot_at_end", "objects_at_end")}) == 3
        # The last scene paid: the cube where the expert left it, the hand back where it started.
        assert torch.allclose(u.obj.pose.p, cube_end, atol=1e-4)
        assert torch.allclose(u.agent.tcp.pose.p, tcp_start, atol=1e-4)
    finally:
        env.close()
