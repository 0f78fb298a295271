"""DREM-by-default env ids and the run-script launcher for ManiSkill's own scripts."""

from __future__ import annotations

import subprocess
import sys
import textwrap
from pathlib import Path

import gymnasium as gym
import pytest
import torch

import drem_maniskill  # noqa: F401

BIN = Path(sys.executable).parent / "drem-maniskill"

STAND_IN = textwrap.dedent('''
    """A stand-in for ManiSkill's baselines: makes the env id from argv, no reward flag, steps it."""
    import argparse
    import gymnasium as gym
    import mani_skill.envs  # noqa: F401  (what ManiSkill's scripts import; not our plugin)
    import torch

    def main():
        parser = argparse.ArgumentParser()
        parser.add_argument("--env_id", required=True)
        parser.add_argument("--steps", type=int, default=2)
        parser.add_argument("--forkserver", action="store_true", help="make the env in a worker, as ppo_cpu.py does")
        args = parser.parse_args()
        if args.forkserver:
            from mani_skill.utils.wrappers.gymnasium import CPUGymWrapper

            make = lambda: CPUGymWrapper(gym.make(args.env_id, obs_mode="state"))  # noqa: E731
            workers = gym.vector.AsyncVectorEnv([make], context="forkserver")
            workers.reset(seed=0)
            _, reward, *_ = workers.step(workers.action_space.sample() * 0)
            print(f"worker reward={float(reward[0]):.4f}")
            workers.close()
        env = gym.make(args.env_id, obs_mode="state", num_envs=1)
        env.reset(seed=0)
        for _ in range(args.steps):
            _, reward, _, _, info = env.step(torch.zeros(env.action_space.shape))
        print(f"__name__={__name__} reward_mode={env.unwrapped.reward_mode} reward={float(reward[0]):.4f} "
              f"success={bool(info['success'][0])}")


    if __name__ == "__main__":  # worker processes import this file too
        main()
''')


def test_alias_defaults_to_drem_and_matches_the_task_with_reward_mode_drem():
    alias = gym.make("PegInHole-DREM-v1")
    plain = gym.make("PegInHole-v1", reward_mode="drem")
    try:
        assert alias.unwrapped.reward_mode == "drem" and alias.unwrapped.env_id == "PegInHole-v1"
        rewards = []
        for env in (alias, plain):
            env.reset(seed=3)
            _, reward, _, _, info = env.step(torch.full((1, 6), 0.3))
            rewards.append(reward)
            assert "success" in info
        torch.testing.assert_close(rewards[0], rewards[1])
    finally:
        alias.close(), plain.close()
    sparse = gym.make("USBInsertion-DREM-v1", reward_mode="sparse")
    try:
        sparse.reset(seed=0)
        _, reward, *_ = sparse.step(torch.zeros(1, 6))
        assert sparse.unwrapped.reward_mode == "sparse" and float(reward[0]) == 0.0
    finally:
        sparse.close()


def test_alias_under_maniskill_vector_env():
    from mani_skill.vector.wrappers.gymnasium import ManiSkillVectorEnv

    env = ManiSkillVectorEnv(gym.make("PegInHole-DREM-v1", obs_mode="state"), auto_reset=True, ignore_terminations=True)
    try:
        env.reset(seed=0)
        _, reward, _, _, info = env.step(torch.zeros(1, 6))
        assert reward.shape == (1,) and -2.0 < float(reward[0]) < 1.5
    finally:
        env.close()


@pytest.mark.slow
def test_launcher_runs_a_script_that_knows_only_maniskill(tmp_path):
    script = tmp_path / "stand_in.py"
    script.write_text(STAND_IN)
    plain = subprocess.run([sys.executable, str(script), "--env_id", "PegInHole-DREM-v1"], capture_output=True, text=True)
    assert plain.returncode != 0 and "PegInHole-DREM" in plain.stderr  # ManiSkill alone does not know our ids
    out = subprocess.run([str(BIN), "run-script", str(script), "--", "--env_id", "PegInHole-DREM-v1", "--steps", "3", "--forkserver"],
                         capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr[-2000:]
    assert "__name__=__main__ reward_mode=drem" in out.stdout and "success=False" in out.stdout
    assert "worker reward=" in out.stdout  # the fork server's workers know our ids too
    # The gymnasium `module:EnvId` form needs no launcher.
    direct = subprocess.run([sys.executable, str(script), "--env_id", "drem_maniskill:USBInsertion-DREM-v1"],
                            capture_output=True, text=True, timeout=300)
    assert direct.returncode == 0 and "reward_mode=drem" in direct.stdout, direct.stderr[-2000:]
    missing = subprocess.run([str(BIN), "run-script", str(tmp_path / "nope.py")], capture_output=True, text=True)
    assert missing.returncode == 2 and "nope.py not found" in missing.stderr
