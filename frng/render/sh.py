"""Real spherical harmonics up to degree 4 (the standard 3DGS / gsplat basis and constants; degree 4 is
RelitLRM's SH order, which stock 3DGS rasterizers stop short of).

Basis order ``l = 0..3, m = -l..l`` (index ``l^2 + l + m``), with the sign convention of the 3DGS reference
code (``Y_1,-1 = -C1 y``, ``Y_1,0 = C1 z``, ``Y_1,1 = -C1 x``, ...). The basis is orthonormal on the sphere,
so projecting a function with ``sh_basis`` and evaluating with :func:`eval_sh` round-trips band-limited
signals (tested).
"""

from __future__ import annotations

import torch

C0 = 0.28209479177387814
C1 = 0.4886025119029199
C2 = (1.0925484305920792, -1.0925484305920792, 0.31539156525252005, -1.0925484305920792, 0.5462742152960396)
C3 = (
    -0.5900435899266435,
    2.890611442640554,
    -0.4570457994644658,
    0.3731763325901154,
    -0.4570457994644658,
    1.445305721320277,
    -0.5900435899266435,
)
C4 = (
    2.5033429417967046,
    -1.7701307697799304,
    0.9461746957575601,
    -0.6690465435572892,
    0.10578554691520431,
    -0.6690465435572892,
    0.47308734787878004,
    -1.7701307697799304,
    0.6258357354491761,
)


def num_coeffs(degree: int) -> int:
    return (degree + 1) ** 2


def sh_basis(degree: int, dirs: torch.Tensor) -> torch.Tensor:
    """Real SH basis (..., (degree + 1)^2) at unit directions (..., 3); degree 0..4."""
    if not 0 <= degree <= 4:
        raise ValueError(f"SH degree must be 0..4, got {degree}")
    x, y, z = dirs.unbind(-1)
    out = [torch.full_like(x, C0)]
    if degree >= 1:
        out += [-C1 * y, C1 * z, -C1 * x]
    if degree >= 2:
        xx, yy, zz, xy, yz, xz = x * x, y * y, z * z, x * y, y * z, x * z
        out += [C2[0] * xy, C2[1] * yz, C2[2] * (2 * zz - xx - yy), C2[3] * xz, C2[4] * (xx - yy)]
    if degree >= 3:
        out += [
            C3[0] * y * (3 * xx - yy),
            C3[1] * xy * z,
            C3[2] * y * (4 * zz - xx - yy),
            C3[3] * z * (2 * zz - 3 * xx - 3 * yy),
            C3[4] * x * (4 * zz - xx - yy),
            C3[5] * z * (xx - yy),
            C3[6] * x * (xx - 3 * yy),
        ]
    if degree >= 4:
        out += [
            C4[0] * xy * (xx - yy),
            C4[1] * yz * (3 * xx - yy),
            C4[2] * xy * (7 * zz - 1),
            C4[3] * yz * (7 * zz - 3),
            C4[4] * (zz * (35 * zz - 30) + 3),
            C4[5] * xz * (7 * zz - 3),
            C4[6] * (xx - yy) * (7 * zz - 1),
            C4[7] * xz * (xx - 3 * yy),
            C4[8] * (xx * (xx - 3 * yy) - yy * (3 * xx - yy)),
        ]
    return torch.stack(out, dim=-1)


def eval_sh(degree: int, coeffs: torch.Tensor, dirs: torch.Tensor) -> torch.Tensor:
    """Evaluate SH functions: coeffs (..., K, C) with K >= (degree + 1)^2, dirs (..., 3) unit -> (..., C).

    For 3DGS-style radiance use ``eval_sh(d, sh, view_dirs) + 0.5`` (the 3DGS DC offset is the caller's choice).
    Leading dims broadcast, e.g. coeffs (N, 16, 3) with dirs (V, N, 3) -> (V, N, 3).
    """
    basis = sh_basis(degree, dirs)  # (..., K')
    k = basis.shape[-1]
    dtype = torch.promote_types(basis.dtype, coeffs.dtype)
    # a batched (1, K') @ (K', C) product (no (..., K', C) temporary, forward or backward); autocast off: in the
    # inputs' precision
    with torch.autocast(device_type=dirs.device.type, enabled=False):
        return torch.einsum("...k,...kc->...c", basis.to(dtype), coeffs[..., :k, :].to(dtype))
