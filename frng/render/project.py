"""EWA projection of 3D Gaussians into pinhole cameras (the shared front end of the PyTorch backend).

Conventions: OpenCV cameras (``frng.camera``), quaternions ``(w, x, y, z)`` (gsplat / 3DGS order, need not be
unit: they are normalised here), ``scales`` are standard deviations along the rotated axes (not log-scales).

The 2D covariance is ``J W Sigma W^T J^T + eps2d * I`` (Zwicker et al. 2002, 3DGS) with the Jacobian's
``x/z, y/z`` clamped to 1.3 x the half field of view (as 3DGS/gsplat do) so that Gaussians far outside the
frustum cannot blow up. The footprint is the exact axis-aligned box of the 3-sigma ellipse; when it is larger
than ``max_radius_px`` the 2D covariance is shrunk (differentiably) so that it fits: this bounds the cost of
the tile binning however large the scales get.

NaN safety: everything that could divide by zero (Gaussians behind the camera, zero scales, zero quaternions)
is computed from sanitised inputs and masked by ``valid``; masked entries carry finite values and zero
gradients.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

SIGMA_CUTOFF = 3.0  # footprint = 3-sigma ellipse; alpha is zero outside it
ALPHA_MIN = 1.0 / 255.0  # contributions below this are skipped (as 3DGS / gsplat)
ALPHA_MAX = 0.99  # per-Gaussian alpha clamp (keeps 1 - alpha > 0: transmittance stays invertible)


def quat_to_rotmat(quats: torch.Tensor) -> torch.Tensor:
    """(..., 4) quaternions (w, x, y, z), any norm -> (..., 3, 3) rotation matrices (zero quaternion -> identity)."""
    q = quats / torch.sqrt((quats * quats).sum(-1, keepdim=True) + 1e-12)
    w, x, y, z = q.unbind(-1)
    return torch.stack(
        [
            1 - 2 * (y * y + z * z),
            2 * (x * y - w * z),
            2 * (x * z + w * y),
            2 * (x * y + w * z),
            1 - 2 * (x * x + z * z),
            2 * (y * z - w * x),
            2 * (x * z - w * y),
            2 * (y * z + w * x),
            1 - 2 * (x * x + y * y),
        ],
        dim=-1,
    ).reshape(q.shape[:-1] + (3, 3))


def rotmat_to_quat(R: torch.Tensor) -> torch.Tensor:
    """(..., 3, 3) rotation matrices -> (..., 4) unit quaternions (w, x, y, z) with w >= 0; the inverse of
    :func:`quat_to_rotmat` (Shepperd's method: of the four candidate solutions, each exact where its own component
    is large, take the one whose component is largest)."""
    assert R.shape[-2:] == (3, 3), R.shape
    m = R.reshape(-1, 3, 3)
    r = {f"{i}{j}": m[:, i, j] for i in range(3) for j in range(3)}
    diag = torch.stack([r["00"] + r["11"] + r["22"], r["00"], r["11"], r["22"]], -1)
    big = torch.stack(  # 4 q_k^2 for k = w, x, y, z
        [
            1 + diag[:, 0],
            1 + 2 * diag[:, 1] - diag[:, 0],
            1 + 2 * diag[:, 2] - diag[:, 0],
            1 + 2 * diag[:, 3] - diag[:, 0],
        ],
        -1,
    )
    sym = [
        r["21"] - r["12"],
        r["02"] - r["20"],
        r["10"] - r["01"],
        r["01"] + r["10"],
        r["02"] + r["20"],
        r["12"] + r["21"],
    ]
    wx, wy, wz, xy, xz, yz = sym
    # candidate k, scaled by 4 q_k: its components from the off-diagonal sums and differences
    cand = torch.stack(
        [
            torch.stack([big[:, 0], wx, wy, wz], -1),
            torch.stack([wx, big[:, 1], xy, xz], -1),
            torch.stack([wy, xy, big[:, 2], yz], -1),
            torch.stack([wz, xz, yz, big[:, 3]], -1),
        ],
        1,
    )  # (N, 4 candidates, 4)
    k = diag.argmax(-1)
    q = cand[torch.arange(m.shape[0], device=R.device), k]
    q = q / q.norm(dim=-1, keepdim=True).clamp_min(1e-12)
    q = torch.where(q[:, :1] < 0, -q, q)
    return q.reshape(R.shape[:-2] + (4,))


def covariance_3d(quats: torch.Tensor, scales: torch.Tensor) -> torch.Tensor:
    """World covariances (N, 3, 3) = R S S^T R^T from quaternions (N, 4) and scales (N, 3) (clamped >= 0)."""
    R = quat_to_rotmat(quats)
    M = R * scales.clamp(min=0.0)[..., None, :]
    return M @ M.transpose(-1, -2)


@dataclass
class Projected:
    """Per (view, Gaussian) screen-space quantities, each with leading dims (V, N)."""

    mean2d: torch.Tensor  # (V, N, 2) pixel coordinates
    conic: torch.Tensor  # (V, N, 3) inverse 2D covariance (a, b, c): sigma = a dx^2 / 2 + b dx dy + c dy^2 / 2
    depth: torch.Tensor  # (V, N) camera z
    extent: torch.Tensor  # (V, N, 2) half-widths (rx, ry) of the 3-sigma box in pixels (no grad)
    valid: torch.Tensor  # (V, N) bool: in front of the near plane and overlapping the image


def project_gaussians(
    means: torch.Tensor,
    quats: torch.Tensor,
    scales: torch.Tensor,
    c2w: torch.Tensor,
    intrinsics: torch.Tensor,
    height: int,
    width: int,
    near: float = 0.01,
    far: float = 1e10,
    eps2d: float = 0.3,
    max_radius_px: float | None = None,
    opacities: torch.Tensor | None = None,
) -> Projected:
    """EWA-project N Gaussians into V cameras. Shapes as in :func:`frng.render.rasterize`.

    With ``opacities`` (N,) the box is opacity-aware: alpha = o exp(-m^2 / 2) drops below 1/255 beyond
    m = sqrt(2 ln(255 o)) sigmas, so the box shrinks to min(3, m) sigmas (same image, fewer tile pairs), and
    Gaussians with o < 1/255 are dropped."""
    V, N = c2w.shape[0], means.shape[0]
    assert means.shape == (N, 3) and quats.shape == (N, 4) and scales.shape == (N, 3), (means.shape, quats.shape)
    assert c2w.shape == (V, 4, 4) and intrinsics.shape == (V, 4), (c2w.shape, intrinsics.shape)
    w2c = torch.linalg.inv(c2w)
    Rw = w2c[:, :3, :3]  # (V, 3, 3)
    p = torch.einsum("vij,nj->vni", Rw, means) + w2c[:, None, :3, 3]  # (V, N, 3)
    z = p[..., 2]
    in_depth = (z > near) & (z < far)
    zs = torch.where(in_depth, z, torch.ones_like(z))  # sanitised: no division by ~0 anywhere
    fx, fy, cx, cy = (intrinsics[:, i, None] for i in range(4))  # (V, 1)
    x, y = p[..., 0], p[..., 1]
    iz = 1.0 / zs
    mean2d = torch.stack([fx * x * iz + cx, fy * y * iz + cy], dim=-1)

    # Jacobian of the perspective projection, with x/z and y/z clamped to 1.3 x the half field of view: its rows are
    # fx/z (1, 0, -ux) and fy/z (0, 1, -uy). The 2D covariance J Rw R S S^T R^T Rw^T J^T is T T^T with T = J Rw R S
    # (V, N, 2, 3), two rows of elementwise products (the same numbers as the 3x3 matrix chain, ~2x faster:
    # batched 3x3 products are slow on CPU; frng.render.reference keeps the matrix form)
    lim_x = 1.3 * (0.5 * width / fx)
    lim_y = 1.3 * (0.5 * height / fy)
    ux = torch.maximum(torch.minimum(x * iz, lim_x), -lim_x)  # (V, N)
    uy = torch.maximum(torch.minimum(y * iz, lim_y), -lim_y)
    M = quat_to_rotmat(quats) * scales.clamp(min=0.0)[..., None, :]  # (N, 3, 3) R S
    Mc = torch.einsum("vij,njk->vnik", Rw, M)  # (V, N, 3, 3) Rw R S
    T0 = (fx * iz)[..., None] * (Mc[..., 0, :] - ux[..., None] * Mc[..., 2, :])  # (V, N, 3)
    T1 = (fy * iz)[..., None] * (Mc[..., 1, :] - uy[..., None] * Mc[..., 2, :])
    a = (T0 * T0).sum(-1) + eps2d
    b = (T0 * T1).sum(-1)
    c = (T1 * T1).sum(-1) + eps2d
    if max_radius_px is not None:  # shrink footprints larger than the cap (keeps shape, bounds cost)
        r2 = SIGMA_CUTOFF**2 * torch.maximum(a, c)
        s = torch.clamp(max_radius_px**2 / r2.clamp(min=1e-12), max=1.0)
        a, b, c = a * s, b * s, c * s
    det = (a * c - b * b).clamp(min=1e-12)  # >= eps2d^2 in exact arithmetic
    conic = torch.stack([c / det, -b / det, a / det], dim=-1)
    with torch.no_grad():
        k = torch.full_like(z, SIGMA_CUTOFF)
        if opacities is not None:
            o = opacities.detach().clamp(min=1e-12) * 255.0
            k = torch.minimum(k, torch.sqrt(2.0 * torch.log(o).clamp(min=0.0))[None])
        extent = k[..., None] * torch.sqrt(torch.stack([a, c], dim=-1))
        m = mean2d.detach()
        on_image = (
            (m[..., 0] + extent[..., 0] > 0)
            & (m[..., 0] - extent[..., 0] < width)
            & (m[..., 1] + extent[..., 1] > 0)
            & (m[..., 1] - extent[..., 1] < height)
        )
        finite = torch.isfinite(m).all(-1) & torch.isfinite(conic.detach()).all(-1)
        valid = in_depth & on_image & finite & (k > 0)
    return Projected(mean2d=mean2d, conic=conic, depth=z, extent=extent, valid=valid)
