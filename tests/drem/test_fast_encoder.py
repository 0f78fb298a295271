"""The reward's fast encoder gives what the straightforward ``model.encode(model.prepare(...))`` gives."""

from __future__ import annotations

import pytest
import torch
import torch.nn.functional as F

from drem_maniskill.drem.model import DREMModel, ModelConfig
from drem_maniskill.drem.reward import DREMReward, default_checkpoint
from tests.conftest import SHIPPED_TASKS

ATOL = 1e-4


def _random_batch(batch: int, px: int, seed: int, cameras=("fixed", "wrist"), ft_history: int = 8) -> dict:
    gen = torch.Generator().manual_seed(seed)
    out = {c: torch.randint(0, 256, (batch, px, px, 3), dtype=torch.uint8, generator=gen) for c in cameras}
    out["ft"] = torch.randn(batch, ft_history, 6, generator=gen) * 20
    return out


def _random_reward(seed: int = 0, **config) -> DREMReward:
    torch.manual_seed(seed)
    model = DREMModel(ModelConfig(**config))
    weights = {f"model.{k}": v for k, v in model.state_dict().items()}
    weights["h_start"], weights["h_goal"] = torch.randn(128), torch.randn(128)
    return DREMReward({"model": model.config.to_dict()}, weights)


@pytest.fixture(scope="module", params=SHIPPED_TASKS)
def shipped(request):
    return DREMReward.from_checkpoint(str(default_checkpoint(request.param)))


@pytest.mark.parametrize("batch", [1, 8])
@pytest.mark.parametrize("px", [128, 64])
def test_fast_path_matches_model_encode_on_shipped_checkpoints(shipped, batch, px):
    inputs = _random_batch(batch, px, seed=batch * 1000 + px)
    with torch.no_grad():
        straight = shipped.model.encode(shipped.model.prepare(inputs))
        fast = shipped.fast_encoder().encode(inputs)  # the fast encoder, whatever the batch size
    torch.testing.assert_close(fast, straight, atol=ATOL, rtol=1e-4)
    reward = shipped(inputs)
    torch.testing.assert_close(reward, shipped.forward_reference(inputs), atol=ATOL, rtol=0)
    assert reward.shape == (batch,) and not reward.requires_grad
    reward[0] = 0.0  # an ordinary tensor, not an inference-mode one: callers may edit it


def test_128_px_images_are_area_downscaled_to_the_model_size(shipped):
    assert shipped.model.config.image_size == 64
    inputs = _random_batch(2, 128, seed=5)
    # What prepare documents: area interpolation of the [0, 1] floats to 64 px.
    small = {
        c: F.interpolate(inputs[c].permute(0, 3, 1, 2).float() / 255.0, size=(64, 64), mode="area")
        for c in ("fixed", "wrist")
    }
    small["ft"] = inputs["ft"] / shipped.model.ft_scale
    with torch.no_grad():
        expected = shipped.model.encode(small)
    torch.testing.assert_close(shipped.embed(inputs), expected, atol=ATOL, rtol=1e-4)
    # A 128 px image made of 2x2 copies of a 64 px one gives the 64 px image's reward.
    base = _random_batch(2, 64, seed=6)
    blown = {c: base[c].repeat_interleave(2, 1).repeat_interleave(2, 2) for c in ("fixed", "wrist")}
    blown["ft"] = base["ft"]
    torch.testing.assert_close(shipped(blown), shipped(base), atol=ATOL, rtol=0)


@pytest.mark.parametrize(
    "config",
    [
        dict(image_size=128),  # 128 px model: a 2x2 last map, fc weights reordered
        dict(image_size=64, modalities=("fixed", "ft"), ft_history=16),  # one camera, a longer F/T history
        dict(image_size=64, modalities=("fixed", "wrist"), ft_history=4),  # the paper's "Image learned"
        dict(image_size=64, modalities=("wrist", "ft"), ft_history=12),  # history not a power of two
    ],
)
@pytest.mark.parametrize("batch", [1, 8])
def test_fast_path_matches_model_encode_for_other_configs(config, batch):
    reward = _random_reward(**config)
    cfg = reward.model.config
    for px in (cfg.image_size, 2 * cfg.image_size, 4 * cfg.image_size):
        inputs = _random_batch(batch, px, seed=px + batch, cameras=cfg.cameras, ft_history=cfg.ft_history)
        with torch.no_grad():
            straight = reward.model.encode(reward.model.prepare(inputs))
            fast = reward.fast_encoder().encode(inputs)
        torch.testing.assert_close(fast, straight, atol=ATOL, rtol=1e-4)
        torch.testing.assert_close(reward(inputs), reward.forward_reference(inputs), atol=ATOL, rtol=0)


def test_inputs_the_fast_path_does_not_take_use_the_model(shipped):
    # 96 px (no integer factor), 32 px (upsampling) and float images go through model.prepare.
    for px in (96, 32):
        inputs = _random_batch(1, px, seed=px)
        assert shipped.fast_encoder().encode(inputs) is None
        torch.testing.assert_close(shipped(inputs), shipped.forward_reference(inputs), atol=ATOL, rtol=0)
    inputs = _random_batch(1, 64, seed=1)
    floats = {c: inputs[c].float() / 255.0 for c in ("fixed", "wrist")} | {"ft": inputs["ft"]}
    assert shipped.fast_encoder().encode(floats) is None
    torch.testing.assert_close(shipped(floats), shipped(inputs), atol=ATOL, rtol=0)


def test_fast_path_follows_new_weights():
    reward = _random_reward(seed=1, image_size=64)
    inputs = _random_batch(1, 128, seed=2)
    before = reward(inputs)
    other = _random_reward(seed=2, image_size=64)
    reward.load_state_dict(other.state_dict())
    torch.testing.assert_close(reward(inputs), other.forward_reference(inputs), atol=ATOL, rtol=0)
    assert not torch.allclose(reward(inputs), before)
    with torch.no_grad():
        reward.model.fusion[2].bias.add_(1.0)
        reward.h_goal.mul_(-1.0)
    torch.testing.assert_close(reward(inputs), reward.forward_reference(inputs), atol=ATOL, rtol=0)


@pytest.mark.parametrize("channels", [slice(0, 3), slice(1, 4)])
def test_rgb_views_of_rgba_images_as_cameras_give_them(shipped, channels):
    # ManiSkill's camera rgb is rgba[..., :3]: the fast path reads the RGBA block and drops alpha.
    gen = torch.Generator().manual_seed(11)
    for batch in (1, 3):
        rgba = {c: torch.randint(0, 256, (batch, 128, 128, 4), dtype=torch.uint8, generator=gen)
                for c in ("fixed", "wrist")}
        views = {c: rgba[c][..., channels] for c in rgba} | {"ft": torch.randn(batch, 8, 6, generator=gen)}
        copies = {c: v.contiguous() for c, v in views.items()}
        assert not views["fixed"].is_contiguous()
        torch.testing.assert_close(shipped(views), shipped(copies), atol=1e-6, rtol=0)
        torch.testing.assert_close(shipped(views), shipped.forward_reference(copies), atol=ATOL, rtol=0)


def test_fast_path_results_are_not_views_of_its_work_buffers(shipped):
    # The fast encoder keeps its intermediate tensors between calls: what it returns must not be one.
    first = _random_batch(1, 128, seed=21)
    second = _random_batch(1, 128, seed=22)
    reward, latent = shipped(first), shipped.embed(first)
    kept_reward, kept_latent = reward.clone(), latent.clone()
    shipped(second), shipped.embed(second)
    assert torch.equal(reward, kept_reward) and torch.equal(latent, kept_latent)
    assert not torch.allclose(shipped(second), kept_reward)


def test_fast_path_switching_batch_sizes_and_image_sizes_keeps_each_right(shipped):
    # Work buffers are kept per batch size and image layout; a call must never read another's.
    cases = [(1, 128, 31), (3, 64, 32), (1, 128, 33), (2, 256, 34), (3, 64, 35)]
    for batch, px, seed in cases + cases[::-1]:
        inputs = _random_batch(batch, px, seed=seed)
        torch.testing.assert_close(shipped(inputs), shipped.forward_reference(inputs), atol=ATOL, rtol=0)


def test_fast_path_gives_each_thread_its_own_result(shipped):
    # Vectorised envs may step in threads: two threads sharing one reward must not share buffers.
    import threading

    inputs = [_random_batch(1, 128, seed=40 + k) for k in range(2)]
    expected = [shipped.forward_reference(x) for x in inputs]
    barrier, errors = threading.Barrier(2), []

    def run(k):
        barrier.wait()
        for _ in range(30):
            got = shipped(inputs[k])
            if not torch.allclose(got, expected[k], atol=ATOL, rtol=0):
                errors.append((k, got, expected[k]))

    threads = [threading.Thread(target=run, args=(k,)) for k in range(2)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert not errors, errors[:2]


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs CUDA: a CPU-simulated env rendering on a GPU")
def test_inputs_on_another_device_go_where_the_reward_is(shipped):
    # ManiSkill's CPU sim rendering on a GPU hands out CUDA images beside CPU F/T (seen on an H200).
    inputs = _random_batch(2, 128, seed=7)
    expected = shipped(inputs)
    mixed = {k: (v.cuda() if k != "ft" else v) for k, v in inputs.items()}
    torch.testing.assert_close(shipped(mixed), expected, atol=ATOL, rtol=0)
    on_gpu = _random_reward(seed=3).cuda()
    cpu_twin = _random_reward(seed=3)
    torch.testing.assert_close(on_gpu(inputs).cpu(), cpu_twin(inputs), atol=ATOL, rtol=1e-4)
