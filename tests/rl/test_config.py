"""RLConfig: presets and what the policy sees."""

from __future__ import annotations

from drem_maniskill.rl import RLConfig


def test_paper_preset_gives_ft_only_to_drem():
    assert RLConfig.preset("paper", reward="drem").uses_ft
    assert not RLConfig.preset("paper", reward="drem-image").uses_ft
    assert RLConfig.preset("light", reward="sparse").uses_ft  # light: the same obs for every reward


def test_a_plain_config_is_the_light_preset_and_saves(tmp_path):
    """The classmethod ``preset`` shares its name with a field: a plain RLConfig() still gets a string there."""
    config = RLConfig()
    assert config.preset == "light" and config.algo == "sac"
    config.save(tmp_path / "config.json")
    assert RLConfig.load(tmp_path / "config.json") == config


def test_run_configs_from_before_the_reward_table_still_load():
    """config.json of runs made before 0.1's re-layering: ``vice`` and ``vice_goal_seeds`` fields, no ``algo``."""
    old = RLConfig.preset("light", reward="vice").to_dict()
    del old["reward_kwargs"], old["algo"]
    plain = dict(old, vice={}, vice_goal_seeds=10)
    assert RLConfig.from_dict(plain) == RLConfig.preset("light", reward="vice")
    tuned = dict(old, vice={"update_every": 16}, vice_goal_seeds=3)
    assert RLConfig.from_dict(tuned).reward_kwargs == {"update_every": 16, "goal_seeds": 3}


def test_state_preset_sees_no_image_and_nothing_a_reward_is_computed_from():
    """Reward studies: proprioception, F/T and the socket's pose; no camera, no ``tip_in_socket``."""
    import torch

    from drem_maniskill.rl.run_env import make_env

    config = RLConfig.preset("state", reward="engineered")
    assert not config.uses_images and config.uses_ft
    env, _ = make_env(config, for_eval=True)
    try:
        u = env.unwrapped
        assert u.obs_mode == "state_dict"  # nothing rendered for the policy
        obs, _ = env.reset(seed=3)
        assert set(obs) == {"ft", "state"}
        assert all(len(s.shape) <= 3 and s.dtype != torch.uint8 for s in env.single_observation_space.values())
        expected = torch.cat([u.agent.robot.get_qpos(), u.agent.robot.get_qvel(), u.agent.tcp.pose.raw_pose,
                              u.socket.pose.raw_pose], dim=1)
        torch.testing.assert_close(obs["state"], expected)
        # The engineered reward is a function of the tip's position in the socket frame: it is not in there.
        tip = u.tip_pose_in_socket().p[0]
        state = obs["state"][0]
        windows = state.unfold(0, 3, 1)
        assert not torch.isclose(windows, tip, atol=1e-4).all(dim=1).any()
    finally:
        env.close()
    # The image presets keep their cameras; DREM's policy alone gets F/T in the paper's.
    assert RLConfig.preset("paper", reward="drem").uses_images and RLConfig.preset("light").uses_images
    assert [RLConfig.preset("paper", reward=r).uses_ft for r in ("drem", "drem-image", "engineered", "sparse", "vice")] == [
        True, False, False, False, False]
