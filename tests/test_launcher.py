"""``drem-maniskill run-script``: ManiSkill-style scripts that know only ManiSkill, run on our ids."""

from __future__ import annotations

import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from drem_maniskill.cli import main
from drem_maniskill.launcher import run_module, run_script

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
            print(f"worker reward_mode={workers.get_attr('reward_mode')[0]} reward={float(reward[0]):.4f}")
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

ECHO = textwrap.dedent('''
    import sys
    import helper_beside_the_script  # importable only if the script's folder is on sys.path
    print("argv", sys.argv[1:], "name", __name__, "helper", helper_beside_the_script.VALUE)
    if "--fail" in sys.argv:
        raise SystemExit(3)
''')


def test_run_script_sets_argv_main_and_the_scripts_folder_then_restores_them(tmp_path, capsys):
    script = tmp_path / "echo.py"
    script.write_text(ECHO)
    (tmp_path / "helper_beside_the_script.py").write_text("VALUE = 42\n")
    argv, path = list(sys.argv), list(sys.path)
    assert main(["run-script", str(script), "--", "--env_id", "PegInHole-DREM-v1", "-x"]) == 0
    assert "argv ['--env_id', 'PegInHole-DREM-v1', '-x'] name __main__ helper 42" in capsys.readouterr().out
    assert sys.argv == argv and sys.path == path
    with pytest.raises(SystemExit) as err:  # the script's own exit code is the command's
        run_script(str(script), ["--fail"])
    assert err.value.code == 3 and sys.argv == argv
    with pytest.raises(FileNotFoundError, match="nope.py not found"):
        run_script(str(tmp_path / "nope.py"), [])


def test_run_module_runs_a_module_as_main(tmp_path, capsys, monkeypatch):
    stand_in = "import types; helper_beside_the_script = types.SimpleNamespace(VALUE=7)"
    (tmp_path / "echo_module.py").write_text(ECHO.replace("import helper_beside_the_script", stand_in))
    monkeypatch.syspath_prepend(str(tmp_path))
    assert main(["run-script", "-m", "echo_module", "--", "-e", "PegInHole-DREM-v1"]) == 0
    assert "argv ['-e', 'PegInHole-DREM-v1'] name __main__ helper 7" in capsys.readouterr().out
    with pytest.raises(FileNotFoundError, match="module no_such.module not found"):
        run_module("no_such.module", [])


@pytest.mark.slow
def test_launcher_runs_a_script_that_knows_only_maniskill(tmp_path, capsys):
    script = tmp_path / "stand_in.py"
    script.write_text(STAND_IN)
    plain = subprocess.run([sys.executable, str(script), "--env_id", "PegInHole-DREM-v1"],
                           capture_output=True, text=True)
    assert plain.returncode != 0 and "PegInHole-DREM" in plain.stderr  # ManiSkill alone does not know our ids
    out = subprocess.run([str(BIN), "run-script", str(script), "--",
                          "--env_id", "PegInHole-DREM-v1", "--steps", "3", "--forkserver"],
                         capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr[-2000:]
    assert "__name__=__main__ reward_mode=drem" in out.stdout and "success=False" in out.stdout
    assert "worker reward_mode=drem reward=" in out.stdout  # the fork server's workers know our ids too
    # The gymnasium `module:EnvId` form needs no launcher.
    direct = subprocess.run([sys.executable, str(script), "--env_id", "drem_maniskill:USBInsertion-DREM-v1"],
                            capture_output=True, text=True, timeout=300)
    assert direct.returncode == 0 and "reward_mode=drem" in direct.stdout, direct.stderr[-2000:]
    assert main(["run-script", str(tmp_path / "nope.py")]) == 2 and "nope.py not found" in capsys.readouterr().err
