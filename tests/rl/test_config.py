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
