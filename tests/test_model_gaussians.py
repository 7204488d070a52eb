"""frng.gaussians: raw per-pixel parameters -> Gaussians (RelitLRM decoding) and the Gaussians container."""

import math

import numpy as np
import pytest
import torch

from frng import camera
from frng.gaussians import (
    FAR,
    NEAR,
    OPACITY_OFFSET,
    SCALE_MAX,
    SCALE_OFFSET,
    GaussianDecodeConfig,
    Gaussians,
    decode,
    decode_raw,
    pixel_gaussians,
)


def rig(V=2, size=16):
    c2w = torch.tensor(
        np.stack([camera.look_at(camera.spherical_to_cartesian(90 * v, 10, 2.6)) for v in range(V)]),
        dtype=torch.float32,
    )
    intr = torch.tensor(camera.intrinsics_from_fov(50, size, size), dtype=torch.float32).expand(V, 4).contiguous()
    return c2w, intr


def test_decode_formulas():
    torch.manual_seed(0)
    raw = torch.randn(5, 7, 9) * 3
    o = torch.randn(5, 7, 3)
    d = torch.nn.functional.normalize(torch.randn(5, 7, 3), dim=-1)
    means, quats, scales, opac = decode_raw(raw, o, d)
    w = torch.sigmoid(raw[..., 0:1])
    t = NEAR * (1 - w) + FAR * w
    torch.testing.assert_close(means, o + d * t)
    torch.testing.assert_close(scales, torch.exp(raw[..., 1:4] - SCALE_OFFSET).clamp(max=SCALE_MAX))
    torch.testing.assert_close(quats, raw[..., 4:8] / raw[..., 4:8].norm(dim=-1, keepdim=True))
    torch.testing.assert_close(opac, torch.sigmoid(raw[..., 8] - OPACITY_OFFSET))
    assert torch.allclose(quats.norm(dim=-1), torch.ones(5, 7))
    # the distance along the ray is bounded by near/far
    dist = ((means - o) * d).sum(-1)
    assert (dist >= NEAR - 1e-5).all() and (dist <= FAR + 1e-5).all()
    assert scales.max() <= SCALE_MAX
    # raw 0 -> scale 0.1, opacity 0.12 (documented)
    m, q, s, a = decode_raw(torch.zeros(1, 9), o[0, :1], d[0, :1])
    assert math.isclose(s[0, 0].item(), math.exp(-2.3), rel_tol=1e-5)
    assert torch.equal(q, torch.tensor([[1.0, 0, 0, 0]]))  # zero quaternion -> identity, no NaN


def test_decode_config_changes_bounds():
    raw = torch.full((3, 9), 50.0)  # sigmoid -> 1 : at far
    o = torch.zeros(3, 3)
    d = torch.tensor([[0.0, 0, 1]]).expand(3, 3)
    means, *_ = decode_raw(raw, o, d, GaussianDecodeConfig(near=1.6, far=3.6))
    torch.testing.assert_close(means[:, 2], torch.full((3,), 3.6))


def test_pixel_gaussians_on_pixel_rays():
    c2w, intr = rig(V=2, size=16)
    raw = torch.randn(2, 16, 16, 9)
    feats = torch.randn(2, 16, 16, 5)
    g = pixel_gaussians(raw, c2w, intr, features=feats)
    assert len(g) == 2 * 16 * 16 and g.features.shape == (512, 5)
    uv, z = camera.project(g.means.reshape(2, 256, 3), c2w, intr)
    expected = camera.pixel_centers(16, 16).reshape(1, 256, 2).expand(2, -1, -1)
    torch.testing.assert_close(uv, expected, atol=1e-3, rtol=0)
    assert (z > 0).all()
    torch.testing.assert_close(g.features, feats.reshape(-1, 5))


def test_gaussians_container():
    a = decode(
        torch.randn(4, 9), torch.zeros(4, 3), torch.tensor([[0.0, 0, 1]]).expand(4, 3), features=torch.ones(4, 2)
    )
    b = a.with_features(torch.zeros(4, 2))
    c = Gaussians.cat([a, b])
    assert len(c) == 8 and c.features.shape == (8, 2)
    assert torch.equal(c[4:].features, torch.zeros(4, 2))
    assert len(c[c.opacities > -1]) == 8
    assert len(c[torch.tensor([0, 5])]) == 2
    assert c.detach().means.requires_grad is False
    with pytest.raises(ValueError):
        Gaussians.cat([a, a.with_features(None)])
    with pytest.raises(ValueError):
        Gaussians(torch.zeros(3, 3), torch.zeros(2, 4), torch.zeros(3, 3), torch.zeros(3))
