"""Gaussian rasterizer: the tile-binned PyTorch backend against the brute-force reference and closed forms.

Tolerances: with early termination off (min_transmittance=0) the tile backend computes the same sums as the
reference in a different order, so float64 results agree to 1e-9 (values and gradients). With early
termination on, a tile stops once every pixel's transmittance is below 1e-4, so outputs may differ by at most
1e-4 x max|feature|.
"""

import math

import numpy as np
import pytest
import torch

from frng import camera
from frng.render import gsplat_backend, rasterize

DT = torch.float64


def _cams(azimuths, H, W, elev=20.0, dist=2.5, fov=50.0):
    c2w = torch.tensor(
        np.stack([camera.look_at(camera.spherical_to_cartesian(a, elev, dist)) for a in azimuths]), dtype=DT
    )
    K = torch.tensor(camera.intrinsics_from_fov(fov, W, H), dtype=DT).expand(len(azimuths), 4).clone()
    return c2w, K


def _scene(N=80, C=4, seed=0):
    g = torch.Generator().manual_seed(seed)
    means = (torch.rand(N, 3, generator=g, dtype=DT) - 0.5) * 1.4
    quats = torch.randn(N, 4, generator=g, dtype=DT)
    scales = torch.rand(N, 3, generator=g, dtype=DT) * 0.1 + 0.01
    op = torch.rand(N, generator=g, dtype=DT) * 0.95 + 0.04
    feats = torch.randn(N, C, generator=g, dtype=DT)
    return [means, quats, scales, op, feats]


def _grads(outs, params, seed=1):
    g = torch.Generator().manual_seed(seed)
    loss = sum((o * torch.randn(o.shape, generator=g, dtype=o.dtype).to(o.device)).sum() for o in outs)
    return torch.autograd.grad(loss, params)


@pytest.mark.parametrize("tile", [4, 8])
@pytest.mark.parametrize("per_view", [False, True])
def test_tiles_match_reference_values_and_gradients(tile, per_view):
    H, W = 22, 26  # not a multiple of the tile size: exercises the cropped border tiles
    c2w, K = _cams([0, 75, 200], H, W)
    params = _scene()
    if per_view:
        params[4] = torch.randn(3, params[0].shape[0], 4, dtype=DT)
    params = [p.clone().requires_grad_() for p in params]
    fast = rasterize(*params, c2w, K, H, W, backend="torch", tile_size=tile, chunk=8, min_transmittance=0.0)
    ref = rasterize(*params, c2w, K, H, W, backend="reference")
    for a, b, name in zip(fast, ref, ["features", "alpha", "depth"]):
        assert a.shape == b.shape
        assert torch.allclose(a, b, atol=1e-9, rtol=0), name
    assert ref[1].max() > 0.9 and (ref[1] == 0).any()  # the scene has opaque and empty pixels
    for ga, gb, name in zip(
        _grads(fast, params), _grads(ref, params), ["means", "quats", "scales", "opacities", "features"]
    ):
        assert torch.isfinite(ga).all()
        assert gb.abs().max() > 0, name
        assert torch.allclose(ga, gb, atol=1e-9 * max(1.0, gb.abs().max().item()), rtol=1e-7), name


def test_early_termination_error_is_bounded_and_float32_matches():
    H, W = 24, 24
    c2w, K = _cams([10, 130], H, W)
    params = _scene(N=300, C=3, seed=3)
    params[3] = torch.full_like(params[3], 0.98)  # opaque: tiles terminate early
    ref = rasterize(*params, c2w, K, H, W, backend="reference")
    fast = rasterize(*[p.float() for p in params], c2w.float(), K.float(), H, W, backend="torch", chunk=16)
    fmax = params[4].abs().max().item()
    assert (fast[0].double() - ref[0]).abs().max() < 1e-4 * fmax + 1e-4
    assert (fast[1].double() - ref[1]).abs().max() < 2e-4


@pytest.mark.parametrize("backend", ["torch", "native"])
def test_gradcheck_tile_backend(backend):
    from frng.render import native

    if backend == "native" and not native.available():
        pytest.skip(f"the C++ rasterizer kernels did not build: {native.reason()}")
    chunk = {"chunk": 2} if backend == "torch" else {}  # torch: several depth chunks per tile
    H, W = 8, 8
    c2w, K = _cams([0], H, W, dist=2.0)
    g = torch.Generator().manual_seed(5)
    N = 3
    means = ((torch.rand(N, 3, generator=g, dtype=DT) - 0.5) * 0.4).requires_grad_()
    quats = torch.randn(N, 4, generator=g, dtype=DT).requires_grad_()
    scales = (torch.rand(N, 3, generator=g, dtype=DT) * 0.05 + 0.08).requires_grad_()
    op = (torch.rand(N, generator=g, dtype=DT) * 0.5 + 0.3).requires_grad_()
    f = torch.randn(N, 2, generator=g, dtype=DT).requires_grad_()

    def fn(*p):
        return rasterize(*p, c2w, K, H, W, backend=backend, tile_size=4, min_transmittance=0.0, **chunk)

    assert torch.autograd.gradcheck(fn, (means, quats, scales, op, f), eps=1e-6, atol=1e-5, rtol=1e-4)


def test_single_gaussian_matches_analytic_2d_gaussian():
    """An axis-aligned Gaussian at distance d on the optical axis projects to N(c, diag(f^2 s^2 / d^2) + eps2d)."""
    H = W = 48
    d, eps2d, op = 3.0, 0.3, 0.8
    c2w = torch.eye(4, dtype=DT)[None]
    f = 40.0
    K = torch.tensor([[f, f, 24.3, 23.6]], dtype=DT)  # off-centre principal point
    sx, sy = 0.15, 0.08
    means = torch.tensor([[0.0, 0.0, d]], dtype=DT)
    quats = torch.tensor([[1.0, 0.0, 0.0, 0.0]], dtype=DT)
    scales = torch.tensor([[sx, sy, 0.05]], dtype=DT)
    feats = torch.tensor([[1.0, 2.0]], dtype=DT)
    out, alpha, depth = rasterize(
        means, quats, scales, torch.tensor([op], dtype=DT), feats, c2w, K, H, W, backend="torch", eps2d=eps2d
    )
    vx, vy = (f * sx / d) ** 2 + eps2d, (f * sy / d) ** 2 + eps2d
    uv = camera.pixel_centers(H, W, dtype=DT)
    m2 = (uv[..., 0] - 24.3) ** 2 / vx + (uv[..., 1] - 23.6) ** 2 / vy
    expect = op * torch.exp(-0.5 * m2)
    expect = torch.where((m2 <= 9.0) & (expect >= 1 / 255), expect, torch.zeros_like(expect))
    assert torch.allclose(alpha[0, ..., 0], expect, atol=1e-12)
    assert torch.allclose(out[0], expect[..., None] * feats[0], atol=1e-12)
    assert torch.allclose(depth[0, ..., 0], expect * d, atol=1e-12)
    # the footprint really is the analytic one: total alpha ~ op * 2 pi sqrt(vx vy) (minus the cut tails)
    assert abs(alpha.sum().item() / (op * 2 * math.pi * math.sqrt(vx * vy)) - 1) < 0.02


@pytest.mark.parametrize("backend", ["torch", "reference"])
def test_depth_ordering_of_two_overlapping_gaussians(backend):
    H = W = 16
    c2w = torch.eye(4, dtype=DT)[None]
    K = torch.tensor([[20.0, 20.0, 8.0, 8.0]], dtype=DT)
    quats = torch.tensor([[1.0, 0, 0, 0]] * 2, dtype=DT)
    scales = torch.full((2, 3), 0.1, dtype=DT)
    op = torch.tensor([0.9, 0.9], dtype=DT)
    red_blue = torch.tensor([[1.0, 0, 0], [0, 0, 1.0]], dtype=DT)
    for z_red, z_blue in [(2.0, 2.1), (2.1, 2.0)]:  # red listed first either way
        means = torch.tensor([[0, 0, z_red], [0.02, 0, z_blue]], dtype=DT)
        out, alpha, _ = rasterize(means, quats, scales, op, red_blue, c2w, K, H, W, backend=backend)
        # each Gaussian alone gives its own alpha map
        a_red = rasterize(means[:1], quats[:1], scales[:1], op[:1], red_blue[:1], c2w, K, H, W, backend=backend)[1][
            0, ..., 0
        ]
        a_blue = rasterize(means[1:], quats[1:], scales[1:], op[1:], red_blue[1:], c2w, K, H, W, backend=backend)[1][
            0, ..., 0
        ]
        if z_red < z_blue:  # red in front: red = a_r, blue = (1 - a_r) a_b
            exp_r, exp_b = a_red, (1 - a_red) * a_blue
        else:
            exp_r, exp_b = (1 - a_blue) * a_red, a_blue
        assert torch.allclose(out[0, ..., 0], exp_r, atol=1e-12)
        assert torch.allclose(out[0, ..., 2], exp_b, atol=1e-12)
        assert torch.allclose(alpha[0, ..., 0], 1 - (1 - a_red) * (1 - a_blue), atol=1e-12)
        front = 0 if z_red < z_blue else 2
        assert out[0, 8, 8, front] > 3 * out[0, 8, 8, 2 - front]


def test_no_nan_for_degenerate_and_behind_camera_gaussians():
    H = W = 16
    c2w, K = _cams([0], H, W, dist=2.0)
    eye = c2w[0, :3, 3]
    means = torch.stack(
        [
            eye,  # exactly at the camera centre
            eye - c2w[0, :3, 2] * 0.5,  # behind the camera
            eye + c2w[0, :3, 2] * 1e-4,  # in front, closer than the near plane
            torch.tensor([0.0, 0, 0], dtype=DT),  # zero scales
            torch.tensor([0.1, 0, 0], dtype=DT),  # zero quaternion
            torch.tensor([0.0, 0.2, 0.1], dtype=DT),  # huge scales
            torch.tensor([5.0, 5.0, 0.0], dtype=DT),  # far outside the frustum
            torch.tensor([0.0, -0.1, 0.0], dtype=DT),  # normal
        ]
    ).requires_grad_()
    quats = torch.randn(8, 4, dtype=DT)
    quats[4] = 0
    quats.requires_grad_()
    scales = torch.full((8, 3), 0.1, dtype=DT)
    scales[3] = 0
    scales[5] = 1e4
    scales.requires_grad_()
    op = torch.full((8,), 0.7, dtype=DT, requires_grad=True)
    f = torch.randn(8, 3, dtype=DT, requires_grad=True)
    for backend in ["torch", "reference"]:
        outs = rasterize(means, quats, scales, op, f, c2w, K, H, W, backend=backend, max_radius_px=8.0)
        assert all(torch.isfinite(o).all() for o in outs)
        grads = _grads(outs, [means, quats, scales, op, f])
        assert all(torch.isfinite(g).all() for g in grads), backend
        assert grads[0][:3].abs().max() == 0  # culled Gaussians get no gradient
    fast = rasterize(means, quats, scales, op, f, c2w, K, H, W, backend="torch", max_radius_px=8.0, min_transmittance=0)
    ref = rasterize(means, quats, scales, op, f, c2w, K, H, W, backend="reference", max_radius_px=8.0)
    assert torch.allclose(fast[0], ref[0], atol=1e-9)


def test_max_radius_clamps_the_footprint():
    H = W = 64
    c2w = torch.eye(4, dtype=DT)[None]
    K = torch.tensor([[60.0, 60.0, 32.0, 32.0]], dtype=DT)
    args = (
        torch.tensor([[0, 0, 2.0]], dtype=DT),
        torch.tensor([[1.0, 0, 0, 0]], dtype=DT),
        torch.full((1, 3), 0.5, dtype=DT),
        torch.tensor([0.5], dtype=DT),
        torch.ones(1, 1, dtype=DT),
        c2w,
        K,
        H,
        W,
    )
    _, free, _ = rasterize(*args, backend="torch")
    _, capped, _ = rasterize(*args, backend="torch", max_radius_px=6.0)
    ys, xs = torch.nonzero(capped[0, ..., 0] > 0, as_tuple=True)
    assert (xs.max() - xs.min() + 1) <= 13 and (free[0, ..., 0] > 0).sum() > 10 * (capped[0, ..., 0] > 0).sum()


@pytest.mark.gpu
def test_gsplat_parity():
    if not gsplat_backend.available():
        reason = "CUDA not available" if not torch.cuda.is_available() else "gsplat not installed"
        print(f"SKIP gsplat parity: {reason}")
        pytest.skip(f"gsplat parity needs CUDA + gsplat: {reason}")
    H, W = 32, 40
    c2w, K = _cams([0, 120], H, W)
    params = _scene(N=200, C=16, seed=7)
    params[3] = params[3].clamp(max=0.34)  # below exp(4.5)/255: both backends cut at the same ellipse
    params = [p.float().cuda().requires_grad_() for p in params]
    c2w, K = c2w.float().cuda(), K.float().cuda()
    a = rasterize(*params, c2w, K, H, W, backend="gsplat")
    b = rasterize(*params, c2w, K, H, W, backend="torch", min_transmittance=0.0)
    for x, y in zip(a, b):
        assert (x - y).abs().max() < 2e-3
    for x, y in zip(_grads(a, params), _grads(b, params)):
        assert torch.allclose(x, y, atol=2e-3 * max(1.0, y.abs().max().item()), rtol=1e-2)
