"""RLConfig: presets and what the policy sees."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from drem_maniskill.rl import RLConfig

ROOT = Path(__file__).resolve().parents[2]


def test_paper_preset_gives_ft_only_to_drem():
    assert RLConfig.from_preset("paper", reward="drem").uses_ft
    assert not RLConfig.from_preset("paper", reward="drem-image").uses_ft
    assert RLConfig.from_preset("light", reward="sparse").uses_ft  # light: the same obs for every reward


COMPARED = ("sparse", "engineered", "vice", "drem-image", "drem")


@pytest.mark.parametrize("reward", ["sparse", "drem-image", "drem"])
def test_image_preset_gives_ft_to_drem_alone_and_the_socket_pose_to_none(reward):
    """The image comparison's inputs (the paper's): both cameras and proprioception; F/T for DREM's policy only."""
    import torch

    from drem_maniskill.rl.run_env import make_env

    configs = {r: RLConfig.from_preset("image", reward=r) for r in COMPARED}
    assert [c.uses_ft for c in configs.values()] == [False, False, False, False, True]
    assert all(c.uses_images and c.image_size == 32 and not c.policy_privileged for c in configs.values())
    assert {(c.steps, c.eval_every) for c in configs.values()} == {(50_000, 2_500)}
    env, _ = make_env(configs[reward], for_eval=True)
    try:
        u = env.unwrapped
        obs, _ = env.reset(seed=5)
        cameras = {"fixed_camera", "wrist_camera"}
        assert set(obs) == cameras | {"state"} | ({"ft"} if reward == "drem" else set())
        assert all(obs[c].shape == (1, 3, 32, 32) and obs[c].dtype == torch.uint8 for c in cameras)
        expected = torch.cat([u.agent.robot.get_qpos(), u.agent.tcp.pose.raw_pose], dim=1)
        torch.testing.assert_close(obs["state"], expected)  # qpos and the TCP pose, nothing after them
        socket = u.socket.pose.raw_pose[0]
        for part in (socket[:3], socket[3:]):  # neither the socket's position nor its orientation is in there
            windows = obs["state"][0].unfold(0, len(part), 1)
            assert not torch.isclose(windows, part, atol=1e-4).all(dim=1).any()
    finally:
        env.close()


def test_a_plain_config_is_the_light_preset_and_saves(tmp_path):
    """A plain RLConfig() names the light preset (without the preset's overrides), and saves and loads back."""
    config = RLConfig()
    assert config.preset == "light" and config.algo == "sac"
    config.save(tmp_path / "config.json")
    assert RLConfig.load(tmp_path / "config.json") == config


def test_every_committed_run_config_loads_as_it_was_saved():
    """The run configs under docs/results hold every field: ``RLConfig.load`` reads each with the one schema."""
    runs = sorted((ROOT / "docs" / "results").rglob("*config.json"))
    assert len(runs) >= 162
    for path in runs:
        assert RLConfig.load(path).to_dict() == json.loads(path.read_text()), path


def test_a_config_missing_a_field_or_holding_an_unknown_key_is_refused():
    saved = RLConfig.from_preset("light", reward="vice").to_dict()
    with pytest.raises(ValueError, match=r"it lacks \['shared_encoder'\]"):
        RLConfig.from_dict({k: v for k, v in saved.items() if k != "shared_encoder"})
    with pytest.raises(ValueError, match=r"it has unknown keys \['vice_goal_seeds'\]"):
        RLConfig.from_dict({**saved, "vice_goal_seeds": 10})


def test_state_preset_sees_no_image_and_nothing_a_reward_is_computed_from():
    """Reward studies: proprioception, F/T and the socket's pose; no camera, no ``tip_in_socket``."""
    import torch

    from drem_maniskill.rl.run_env import make_env

    config = RLConfig.from_preset("state", reward="engineered")
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
    assert RLConfig.from_preset("paper", reward="drem").uses_images and RLConfig.from_preset("light").uses_images
    rewards = ("drem", "drem-image", "engineered", "sparse", "vice")
    assert [RLConfig.from_preset("paper", reward=r).uses_ft for r in rewards] == [True, False, False, False, False]


def test_running_norm_learns_the_statistics_in_training_and_keeps_them_in_evaluation():
    """``obs_norm``: inputs of any scale come out about zero-mean, unit-variance; evaluation keeps the statistics."""
    import torch

    from drem_maniskill.rl.policy import RunningNorm

    torch.manual_seed(0)
    norm = RunningNorm((3,))
    scale, shift = torch.tensor([0.001, 1.0, 100.0]), torch.tensor([0.5, -2.0, 30.0])
    for _ in range(50):
        norm(torch.randn(256, 3) * scale + shift)
    out = norm(torch.randn(4096, 3) * scale + shift)
    torch.testing.assert_close(out.mean(0), torch.zeros(3), atol=0.05, rtol=0)
    torch.testing.assert_close(out.std(0), torch.ones(3), atol=0.05, rtol=0)
    norm.eval()
    before = norm.running_mean.clone()
    norm(torch.full((8, 3), 1e6))
    assert torch.equal(norm.running_mean, before)
    assert norm(torch.full((1, 3), 1e6)).max() == norm.clip  # clipped, not exploding


def test_obs_norm_and_action_scale_reach_the_policy_and_the_controller():
    """``--obs-norm`` puts a RunningNorm before the named inputs (and copies it to the critic's target);
    ``--action-scale s`` makes the policy's full action a fraction s of the controller's step."""
    import numpy as np
    import pytest
    import torch

    from drem_maniskill.rl.algos import build_sac
    from drem_maniskill.rl.policy import RunningNorm
    from drem_maniskill.rl.run_env import make_env
    from drem_maniskill.rl.vec_env import ManiSkillDictVecEnv

    moved = {}
    for scale in (1.0, 0.25):
        env, _ = make_env(RLConfig.from_preset("state", reward="engineered", action_scale=scale), for_eval=True)
        try:
            env.reset(seed=2)
            start = env.unwrapped.agent.tcp.pose.p.clone()
            for _ in range(2):
                env.step(torch.tensor([[1.0, 0, 0, 0, 0, 0]]))
            moved[scale] = float((env.unwrapped.agent.tcp.pose.p - start)[0, 0])
        finally:
            env.close()
    assert moved[1.0] > 0.02  # two full steps of up to 2 cm
    assert moved[0.25] == pytest.approx(moved[1.0] / 4, rel=0.15)

    config = RLConfig.from_preset("state", reward="engineered", obs_norm=("state", "ft"), steps=300)
    env, _ = make_env(config)
    venv = ManiSkillDictVecEnv(env, 50)
    try:
        model = build_sac(config, venv)
        norms = {name: m for name, m in model.policy.named_modules() if isinstance(m, RunningNorm)}
        assert {n.rsplit(".", 3)[0] for n in norms} == {"actor.features_extractor", "critic.features_extractor",
                                                        "critic_target.features_extractor"}
        assert len(norms) == 6  # state and ft in each
        model.learning_starts = 50
        model.learn(120)
        critic = dict(model.critic.named_buffers())
        target = dict(model.critic_target.named_buffers())
        mean = critic["features_extractor.encoders.state.0.running_mean"]
        assert not np.allclose(mean.numpy(), 0)  # it learnt the qpos, tcp and socket statistics
        torch.testing.assert_close(target["features_extractor.encoders.state.0.running_mean"], mean)
    finally:
        venv.close()
    with pytest.raises(ValueError, match="obs_norm takes 'state' and 'ft'"):
        RLConfig.from_preset("state", obs_norm=("fixed_camera",))
    with pytest.raises(ValueError, match=r"action_scale must be in \(0, 1\]"):
        RLConfig.from_preset("state", action_scale=0)


@pytest.mark.parametrize("native", [True, False])
def test_state_preset_takes_bfloat16_only_where_the_cpu_has_it(monkeypatch, native):
    """Emulated bfloat16 made the state preset 6.5-6.9x slower (docs/rl.md, "Speed"): the preset asks the CPU.

    ``--bf16`` still decides.
    """
    import drem_maniskill.rl.config as config_module

    monkeypatch.setattr(config_module, "native_bf16", lambda: native)
    assert RLConfig.from_preset("state").train_bf16 is native
    assert RLConfig.from_preset("state", train_bf16=not native).train_bf16 is (not native)
    assert RLConfig.from_preset("light").train_bf16 is False


def test_native_bf16_reads_torchs_cpu_checks(monkeypatch):
    """AVX512-BF16 or AMX counts; neither, or a torch without the checks, does not."""
    import torch

    from drem_maniskill.rl.config import native_bf16

    for avx512, amx, expected in ((False, False, False), (True, False, True), (False, True, True)):
        monkeypatch.setattr(torch.cpu, "_is_avx512_bf16_supported", lambda v=avx512: v, raising=False)
        monkeypatch.setattr(torch.cpu, "_is_amx_tile_supported", lambda v=amx: v, raising=False)
        assert native_bf16() is expected
    monkeypatch.delattr(torch.cpu, "_is_avx512_bf16_supported")
    monkeypatch.delattr(torch.cpu, "_is_amx_tile_supported")
    assert native_bf16() is False


def test_state_preset_on_a_stock_task_sees_its_object_and_goal_poses():
    """ManiSkill's state observation gives every policy the task's objects: so does the state preset on its tasks."""
    import torch

    from drem_maniskill.rl.run_env import make_env

    env, _ = make_env(RLConfig.from_preset("state", task="PegInsertionSide-v1", reward="sparse"), for_eval=True)
    try:
        u = env.unwrapped
        obs, _ = env.reset(seed=2)
        assert set(obs) == {"state"}
        robot = [u.agent.robot.get_qpos(), u.agent.robot.get_qvel(), u.agent.tcp.pose.raw_pose]
        # The peg's pose, its half size, the hole's pose and radius: ManiSkill's obs["extra"] in its order.
        task = [u.peg.pose.raw_pose, u.peg_half_sizes, u.box_hole_pose.raw_pose, u.box_hole_radii[:, None]]
        torch.testing.assert_close(obs["state"], torch.cat(robot + task, dim=1))
    finally:
        env.close()
