"""Our ids in ManiSkill's and gymnasium's registries, and gymnasium's lazy ``module:id`` form.

Everything here and in the other tests of ManiSkill's tooling (wrappers, RecordEpisode, the benchmark
runner, obs modes) runs on the CPU simulation with one env and few steps."""

from __future__ import annotations

import json
import textwrap

import gymnasium as gym
import pytest

import drem_maniskill  # noqa: F401  (registers the tasks; conftest imports it too)
from tests.envs.tooling import (
    FT_HISTORY,
    IDS,
    fail_msg,
    run_subprocess,
)

pytestmark = [
    pytest.mark.filterwarnings("ignore::UserWarning"),
    pytest.mark.filterwarnings("ignore::DeprecationWarning"),
]


def test_gym_make_module_prefixed_id_in_fresh_process(tmp_path):
    code = textwrap.dedent(
        """
        import json, sys
        import gymnasium as gym
        assert "drem_maniskill" not in sys.modules
        assert "PegInHole-v1" not in gym.envs.registry
        env = gym.make("drem_maniskill:PegInHole-v1", obs_mode="state_dict")
        obs, info = env.reset(seed=0)
        obs, reward, terminated, truncated, info = env.step(env.action_space.sample())
        print("RESULT=" + json.dumps(dict(
            cls=type(env.unwrapped).__name__,
            module=type(env.unwrapped).__module__,
            spec_id=env.unwrapped.spec.id,
            imported="drem_maniskill" in sys.modules,
            obs_keys=sorted(obs),
            extra=sorted(obs["extra"]),
            ft=list(obs["extra"]["ft"].shape),
            elapsed=int(info["elapsed_steps"].item()),
        )))
        env.close()
        """
    )
    proc = run_subprocess(["-c", code], cwd=tmp_path)
    assert proc.returncode == 0, fail_msg(proc)
    line = next(out for out in proc.stdout.splitlines() if out.startswith("RESULT="))
    res = json.loads(line[len("RESULT="):])
    assert res["cls"] == "PegInHoleEnv"
    assert res["module"] == "drem_maniskill.envs.peg_in_hole"
    assert res["spec_id"] == "PegInHole-v1"
    assert res["imported"] is True
    assert res["obs_keys"] == ["agent", "extra"]
    assert res["extra"] == ["ft", "part_pose", "socket_pose", "tcp_pose", "tip_in_socket"]
    assert res["ft"] == [1, FT_HISTORY, 6]
    assert res["elapsed"] == 1


@pytest.mark.parametrize("env_id", sorted(IDS))
def test_registered_in_maniskill_and_gymnasium(env_id):
    from mani_skill.utils.registration import REGISTERED_ENVS

    assert env_id in REGISTERED_ENVS
    ms_spec = REGISTERED_ENVS[env_id]
    assert ms_spec.cls is IDS[env_id]
    assert ms_spec.max_episode_steps == 50

    assert env_id in gym.envs.registry
    spec = gym.envs.registry[env_id]
    assert spec.max_episode_steps == 50
    # ManiSkill's entry point is partial(mani_skill...make, env_id=<id>)
    assert getattr(spec.entry_point, "keywords", {}).get("env_id") == env_id
    assert [w.name for w in spec.additional_wrappers] == ["MSTimeLimit"]
    assert gym.spec(env_id) is spec
