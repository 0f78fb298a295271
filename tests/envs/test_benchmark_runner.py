"""ManiSkill's benchmark runner (mani_skill.examples.benchmarking.gpu_sim) on our ids."""

from __future__ import annotations

import os
import re
import textwrap

import pytest

import drem_maniskill  # noqa: F401  (registers the tasks; conftest imports it too)
from tests.envs.tooling import (
    STATE_DIM,
    fail_msg,
    run_subprocess,
)

pytestmark = [
    pytest.mark.filterwarnings("ignore::UserWarning"),
    pytest.mark.filterwarnings("ignore::DeprecationWarning"),
]


_FPS = re.compile(r"^env\.step: ([0-9.]+) steps/s", re.M)


_FPS_RESET = re.compile(r"^env\.step\+env\.reset: ([0-9.]+) steps/s", re.M)


def test_gpu_sim_benchmark_cpu_state(tmp_path):
    """The unmodified runner (1000 + 1000 random steps) with the state obs mode."""
    proc = run_subprocess(
        ["-m", "mani_skill.examples.benchmarking.gpu_sim", "-e", "drem_maniskill:PegInHole-v1",
         "--cpu-sim", "-n", "1", "-o", "state"],
        cwd=tmp_path,
    )
    assert proc.returncode == 0, fail_msg(proc)
    out = proc.stdout
    assert "Task ID: PegInHole-v1, 1 parallel environments, sim_backend=physx_cpu" in out
    assert "obs_mode=state, control_mode=pd_joint_delta_pos" in out
    assert "sim_freq=120, control_freq=60" in out  # the runner overrides the task's 100/5 Hz
    assert f"observation space: Box(-inf, inf, (1, {STATE_DIM}), float32)" in out
    for pattern in (_FPS, _FPS_RESET):
        m = pattern.search(out)
        assert m, fail_msg(proc)
        assert float(m.group(1)) > 0


def test_gpu_sim_benchmark_cpu_rgb_short(tmp_path):
    """The runner's code path with rgb obs, our control mode and the task's own sim/control rates.

    The runner hard-codes 1000 steps per phase (~80 s with rgb here), so this run shortens its
    loops by shadowing ``range`` in the module; the printed FPS therefore is not meaningful.
    """
    code = textwrap.dedent(
        """
        import builtins, sys, tyro
        import mani_skill.examples.benchmarking.gpu_sim as gpu_sim
        gpu_sim.range = lambda n: builtins.range(min(n, 5))
        gpu_sim.main(tyro.cli(gpu_sim.Args, args=sys.argv[1:]))
        """
    )
    proc = run_subprocess(
        ["-c", code, "-e", "drem_maniskill:PegInHole-v1", "--cpu-sim", "-n", "1", "-o", "rgb",
         "-c", "pd_ee_delta_pose", "--sim-freq", "None", "--control-freq", "None"],
        cwd=tmp_path,
    )
    assert proc.returncode == 0, fail_msg(proc)
    out = proc.stdout
    assert "obs_mode=rgb, control_mode=pd_ee_delta_pose" in out
    assert "sim_freq=100, control_freq=5" in out
    assert "sensor_details=RGBD(128x128), RGBD(128x128)" in out
    assert "'ft': Box(-inf, inf, (1, 8, 6), float32)" in out
    assert _FPS.search(out) and _FPS_RESET.search(out), fail_msg(proc)


def test_gpu_sim_benchmark_on_the_drem_alias_runs_with_drem(tmp_path):
    """The runner with no reward flag on ``drem_maniskill:PegInHole-DREM-v1`` (gymnasium's module:id form)
    steps an env whose reward is DREM; loops shortened as above, gym.make watched to report the mode."""
    code = textwrap.dedent(
        """
        import builtins, sys, tyro
        import mani_skill.examples.benchmarking.gpu_sim as gpu_sim
        gpu_sim.range = lambda n: builtins.range(min(n, 5))
        make = gpu_sim.gym.make
        def watched(*args, **kwargs):
            env = make(*args, **kwargs)
            print("made", env.unwrapped.spec.id, "reward_mode", env.unwrapped.reward_mode)
            return env
        gpu_sim.gym.make = watched
        gpu_sim.main(tyro.cli(gpu_sim.Args, args=sys.argv[1:]))
        """
    )
    proc = run_subprocess(["-c", code, "-e", "drem_maniskill:PegInHole-DREM-v1", "--cpu-sim", "-n", "1", "-o", "state"],
                          cwd=tmp_path)
    assert proc.returncode == 0, fail_msg(proc)
    assert "made PegInHole-DREM-v1 reward_mode drem" in proc.stdout, fail_msg(proc)
    assert _FPS.search(proc.stdout), fail_msg(proc)


@pytest.mark.slow
@pytest.mark.skipif(not os.environ.get("DREM_FULL_BENCH"), reason="~80 s; set DREM_FULL_BENCH=1 to run")
def test_gpu_sim_benchmark_cpu_rgb_full(tmp_path):
    proc = run_subprocess(
        ["-m", "mani_skill.examples.benchmarking.gpu_sim", "-e", "drem_maniskill:PegInHole-v1",
         "--cpu-sim", "-n", "1", "-o", "rgb", "-c", "pd_ee_delta_pose"],
        cwd=tmp_path, timeout=900,
    )
    assert proc.returncode == 0, fail_msg(proc)
    assert float(_FPS.search(proc.stdout).group(1)) > 0
