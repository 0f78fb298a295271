"""Shared fixtures: one env per task and obs mode per test session (creating one costs seconds), the tiny DREM chain."""

from __future__ import annotations

import json
import os

import gymnasium as gym
import pytest
import torch
from filelock import FileLock

from drem_maniskill.drem.checkpoint import default_checkpoint, save_checkpoint
from drem_maniskill.drem.model import DREMModel, ModelConfig
from drem_maniskill.envs import TASKS  # noqa: F401  (the tests' task parameter; importing registers the tasks)
from drem_maniskill.experts import get_policy, record_expert, rollout
from drem_maniskill.pipeline import SamplerConfig, backward_sample
from drem_maniskill.pipeline.train_reward import TrainConfig, train_reward
from drem_maniskill.version import __version__

_cache: dict = {}
# Our tasks whose DREM reward ships in rewards/<id>/ (a task added to TASKS ships one once it is built).
SHIPPED_TASKS = tuple(task for task in TASKS if default_checkpoint(task).is_file())

if os.environ.get("PYTEST_XDIST_WORKER"):
    torch.set_num_threads(1)  # one xdist worker per core: two torch threads each would oversubscribe it
    # The processes a test starts (CLI commands, the wheel's demo, resumed runs) run on their worker's core too, while
    # it waits on them: one thread each, and OpenMP threads that sleep rather than spin when idle.
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")


def make_env(task: str, **kwargs):
    """A cached env; tests must reset it themselves."""
    key = (task, tuple(sorted(kwargs.items())))
    if key not in _cache:
        _cache[key] = gym.make(task, **kwargs)
    return _cache[key]


def pytest_collection_modifyitems(config, items):
    """The slow tests first: with one xdist worker per core, a long test left for last would run alone at the end."""
    items.sort(key=lambda item: item.get_closest_marker("slow") is None)


@pytest.fixture(scope="session", autouse=True)
def _close_envs():
    yield
    for env in _cache.values():
        env.close()
    _cache.clear()


@pytest.fixture(scope="session", autouse=True)
def _sb3_logs_in_pytest_tmp(tmp_path_factory):
    """SB3 models that learn without a logger of ours write under pytest's temporary folder, not in /tmp itself."""
    os.environ["SB3_LOGDIR"] = str(tmp_path_factory.mktemp("sb3"))


@pytest.fixture(scope="session")
def pipeline(tmp_path_factory):
    """Record one expert episode, sample a tiny tree, train a tiny reward (about a minute); read-only for tests.

    Built once per test run: under xdist the first worker to need it builds it in the run's shared temporary folder
    while the others wait on its lock, then read what it wrote.
    """
    base = tmp_path_factory.getbasetemp()
    shared = base.parent if os.environ.get("PYTEST_XDIST_WORKER") else base
    root = shared / "drem_pipeline"
    with FileLock(str(shared / "drem_pipeline.lock")):
        done = root / "pipeline.json"
        if not done.is_file():
            rec = record_expert("PegInHole-v1", str(root / "expert"), seeds=[5], obs_mode="rgb")
            tree = backward_sample(rec.h5_path, str(root / "tree.h5"), SamplerConfig.preset("tiny"), progress=False)
            ckpt = train_reward(tree, str(root / "reward"), TrainConfig.preset("tiny"), progress=False)
            done.write_text(json.dumps(dict(expert=str(rec.h5_path), tree=str(tree), checkpoint=str(ckpt))))
    return dict(root=root, **json.loads(done.read_text()))


def tiny_checkpoint(path, env_id: str, modalities=("fixed", "wrist", "ft"),
                    camera_uids=("fixed_camera", "wrist_camera"), **model) -> str:
    """An untrained, tiny DREM checkpoint for ``env_id``; ``model``: other ``ModelConfig`` fields.

    Stock tasks: ``modalities=("fixed", "wrist")`` and their cameras.
    """
    torch.manual_seed(0)
    config = ModelConfig(modalities=modalities, image_size=64, image_dim=8, latent_dim=16, channels=(4,) * 6, **model)
    model = DREMModel(config)
    header = dict(env_id=env_id, env_kwargs={}, modalities=list(config.modalities), camera_uids=list(camera_uids),
                  image_size=config.image_size, ft_history=config.ft_history, render_style="lean",
                  model=config.to_dict(), train={}, sampler={}, package_version=__version__)
    weights = {f"model.{k}": v for k, v in model.state_dict().items()}
    weights["h_start"], weights["h_goal"] = torch.randn(16), torch.randn(16)
    return save_checkpoint(str(path), header, weights)


def tiny_stock_checkpoint(path, env_id: str = "PegInsertionSide-v1") -> str:
    """An untrained image-only checkpoint for a stock task (its base and hand cameras)."""
    return tiny_checkpoint(path, env_id, ("fixed", "wrist"), ("base_camera", "hand_camera"))


def run_policy(env, name: str, seed: int, steps: int = 50, stop_on_success: bool = True, policy_seed: int = 0):
    """Run a scripted policy for one episode; returns the last (obs, info) and the step count."""
    ep = rollout(env, get_policy(name, env, seed=policy_seed), seed, steps, stop_on_success=stop_on_success)
    return ep.obs, ep.info, ep.length


def hand_to_part(env) -> "torch.Tensor":
    """Raw pose ``[B, 7]`` of the part in the hand frame."""
    u = env.unwrapped
    return (u.agent.robot.links_map["panda_hand"].pose.inv() * u.part.pose).raw_pose
