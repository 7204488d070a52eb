"""Brute-force per-pixel Gaussian rasterizer: the readable reference the fast backends are tested against.

Every pixel of every view composites *all* Gaussians sorted by depth, with no tiles, no early termination and
no chunking; the projection is written out independently of :mod:`frng.render.project` (explicit Jacobian,
per view). Same rules as the fast path: quaternions (w, x, y, z), ``eps2d`` low-pass, a Gaussian contributes
only inside its 3-sigma ellipse and where alpha >= 1/255, alpha clamped to 0.99, depth = sum of w_i z_i.
Memory is O(V H W N): for tests on small scenes only.
"""

from __future__ import annotations

import torch

from frng import camera
from frng.render.project import ALPHA_MAX, ALPHA_MIN, SIGMA_CUTOFF, covariance_3d


def rasterize_reference(
    means,
    quats,
    scales,
    opacities,
    features,
    c2w,
    intrinsics,
    height,
    width,
    near=0.01,
    far=1e10,
    eps2d=0.3,
    max_radius_px=None,
):
    """Same signature and outputs as :func:`frng.render.rasterize` (``features`` (N, C) or (V, N, C))."""
    V, N = c2w.shape[0], means.shape[0]
    cov3 = covariance_3d(quats, scales)
    uv = camera.pixel_centers(height, width, device=means.device, dtype=means.dtype).reshape(-1, 2)
    outs_f, outs_a, outs_d = [], [], []
    for v in range(V):
        w2c = torch.linalg.inv(c2w[v])
        R, t = w2c[:3, :3], w2c[:3, 3]
        p = means @ R.T + t
        x, y, z = p[:, 0], p[:, 1], p[:, 2]
        fx, fy, cx, cy = intrinsics[v]
        ok = (z > near) & (z < far)
        z1 = torch.where(ok, z, torch.ones_like(z))
        u = torch.stack([fx * x / z1 + cx, fy * y / z1 + cy], -1)
        limx, limy = 1.3 * 0.5 * width / fx, 1.3 * 0.5 * height / fy
        txz = (x / z1).clamp(-limx, limx)
        tyz = (y / z1).clamp(-limy, limy)
        J = torch.zeros(N, 2, 3, dtype=means.dtype, device=means.device)
        J[:, 0, 0] = fx / z1
        J[:, 0, 2] = -fx * txz / z1
        J[:, 1, 1] = fy / z1
        J[:, 1, 2] = -fy * tyz / z1
        cov2 = J @ (R @ cov3 @ R.T) @ J.transpose(1, 2) + eps2d * torch.eye(2, dtype=means.dtype)
        if max_radius_px is not None:
            r2 = SIGMA_CUTOFF**2 * torch.maximum(cov2[:, 0, 0], cov2[:, 1, 1])
            cov2 = cov2 * torch.clamp(max_radius_px**2 / r2, max=1.0)[:, None, None]
        inv = torch.linalg.inv(cov2)  # (N, 2, 2)
        d = uv[:, None, :] - u[None]  # (HW, N, 2)
        maha = torch.einsum("pni,nij,pnj->pn", d, inv, d)
        alpha = opacities.clamp(0, 1)[None] * torch.exp(-0.5 * maha)
        keep = (maha <= SIGMA_CUTOFF**2) & (alpha >= ALPHA_MIN) & ok[None]
        alpha = torch.where(keep, alpha.clamp(max=ALPHA_MAX), torch.zeros_like(alpha))
        order = torch.argsort(torch.where(ok, z, torch.full_like(z, float("inf"))), stable=True)
        a = alpha[:, order]
        T = torch.cumprod(torch.cat([torch.ones_like(a[:, :1]), 1 - a[:, :-1]], 1), 1)
        w = a * T
        f = features if features.dim() == 2 else features[v]
        outs_f.append((w @ f[order]).reshape(height, width, -1))
        outs_a.append(w.sum(1).reshape(height, width, 1))
        outs_d.append((w @ z[order]).reshape(height, width, 1))
    return torch.stack(outs_f), torch.stack(outs_a), torch.stack(outs_d)
