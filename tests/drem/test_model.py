"""The multimodal encoder-decoder: shapes per modality set, resizing, config errors."""

from __future__ import annotations

import math

import pytest
import torch

from drem_maniskill.drem.model import DREMModel, ModelConfig, cosine_distance


def _batch(b, size=128, modalities=("fixed", "wrist", "ft")):
    out = {c: torch.randint(0, 255, (b, size, size, 3), dtype=torch.uint8) for c in modalities if c != "ft"}
    out["ft"] = torch.randn(b, 8, 6)
    return out


@pytest.mark.parametrize("modalities", [("fixed", "wrist", "ft"), ("fixed", "wrist"), ("wrist", "ft")])
def test_model_shapes(modalities):
    model = DREMModel(ModelConfig(modalities=modalities))
    h, recon, inputs = model(_batch(3, modalities=modalities))
    assert h.shape == (3, 128)
    for c in model.config.cameras:
        assert recon[c].shape == (3, 3, 128, 128)
    assert ("ft" in recon) == ("ft" in modalities)
    if "ft" in recon:
        assert recon["ft"].shape == (3, 8, 6)
    # Paper's architecture: 6 conv layers per image encoder, 4 causal F/T layers.
    enc = next(iter(model.image_encoders.values()))
    assert sum(isinstance(m, torch.nn.Conv2d) for m in enc.modules()) == 6
    dec = next(iter(model.image_decoders.values()))
    assert sum(isinstance(m, torch.nn.ConvTranspose2d) for m in dec.modules()) == 7


def test_model_resizes_other_image_sizes():
    model = DREMModel(ModelConfig(image_size=64)).eval()
    big = _batch(2, size=128)

    def area(v):
        shrunk = torch.nn.functional.interpolate(v.permute(0, 3, 1, 2).float(), size=(64, 64), mode="area")
        return shrunk.round().to(torch.uint8).permute(0, 2, 3, 1)

    small = {k: (area(v) if k != "ft" else v) for k, v in big.items()}
    with torch.no_grad():
        h_big = model.encode(model.prepare(big))
        h_small = model.encode(model.prepare(small))
    torch.testing.assert_close(h_big, h_small, atol=0.05, rtol=0.05)


def test_bad_model_config_is_a_clear_error():
    with pytest.raises(ValueError, match="modalities"):
        ModelConfig(modalities=("fixed", "sonar"))
    with pytest.raises(ValueError, match="multiple of 64"):
        ModelConfig(image_size=100)


def test_cosine_distance():
    a = torch.tensor([[1.0, 0.0], [0.0, 2.0], [1.0, 1.0]])
    g = torch.tensor([[3.0, 0.0]])
    torch.testing.assert_close(cosine_distance(a, g), torch.tensor([0.0, 1.0, 1 - 1 / math.sqrt(2)]))
    assert cosine_distance(-g, g).item() == pytest.approx(2.0)
