"""Least-squares spherical-harmonic fits of per-Gaussian functions on the sphere (``frng export-asset``'s bake).

A baked Gaussian's colour is a function c(d) of the 3DGS view direction d (unit, camera -> Gaussian); plain 3DGS
stores it as real SH of degree <= 3 in the basis of :func:`frng.render.sh.sh_basis` (the 3DGS reference order and
signs, which KHR_gaussian_splatting's Appendix A repeats), evaluated as ``sum_k coeffs[k] Y_k(d) + 0.5``. This
module fits those coefficients to samples of c on a set of directions and scores the fit on other directions.

Directions: :func:`fibonacci_sphere` (near-uniform, deterministic); the fit uses one set and the score a second
set rotated away from it (:func:`held_out_directions`), so the score measures the fit between its samples.
"""

from __future__ import annotations

import math

import torch

from frng.render.sh import num_coeffs, sh_basis

SH_DEGREE = 3  # what 3DGS, SPZ and KHR_gaussian_splatting store at most


def fibonacci_sphere(n: int, offset: float = 0.5, dtype: torch.dtype = torch.float64) -> torch.Tensor:
    """``n`` near-uniform unit directions (n, 3) on the sphere (a Fibonacci lattice; ``offset`` in [0, 1) shifts it
    along z, so two offsets give disjoint sets)."""
    assert n >= 1 and 0.0 <= offset < 1.0, (n, offset)
    i = torch.arange(n, dtype=dtype)
    z = 1.0 - 2.0 * (i + offset) / n
    r = torch.sqrt((1.0 - z * z).clamp_min(0.0))
    phi = i * math.pi * (3.0 - math.sqrt(5.0))
    return torch.stack([r * torch.cos(phi), r * torch.sin(phi), z], -1)


def held_out_directions(n: int, dtype: torch.dtype = torch.float64) -> torch.Tensor:
    """``n`` directions (n, 3) between those of :func:`fibonacci_sphere`: the lattice shifted half a step along z and
    turned 1 radian about z (none coincides with a fit direction)."""
    d = fibonacci_sphere(n, 0.0, dtype) if n > 1 else torch.tensor([[1.0, 0.0, 0.0]], dtype=dtype)
    c, s = math.cos(1.0), math.sin(1.0)
    rot = torch.tensor([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]], dtype=dtype)
    return d @ rot.T


def fit_sh(values: torch.Tensor, dirs: torch.Tensor, degree: int = SH_DEGREE, ridge: float = 1e-6) -> torch.Tensor:
    """Least-squares SH coefficients of sampled functions: values (N, D, C) at unit directions dirs (D, 3) ->
    coefficients (N, K, C), K = (degree + 1)^2, minimising sum_d |sum_k c_k Y_k(d) - v(d)|^2 (+ ``ridge`` |c|^2,
    which only matters when D < K or the directions are degenerate). One (K, K) solve shared by every Gaussian and
    channel, in float64."""
    assert values.dim() == 3 and dirs.dim() == 2 and dirs.shape == (values.shape[1], 3), (values.shape, dirs.shape)
    Y = sh_basis(degree, dirs.double())  # (D, K)
    k = Y.shape[1]
    assert k == num_coeffs(degree), (k, degree)
    gram = Y.T @ Y + ridge * torch.eye(k, dtype=torch.float64)
    n, c = values.shape[0], values.shape[2]
    rhs = torch.einsum("dk,ndc->knc", Y, values.double()).reshape(k, n * c)  # (K, N C)
    coeffs = torch.linalg.solve(gram, rhs).reshape(k, n, c).permute(1, 0, 2)
    assert coeffs.shape == (n, k, c), coeffs.shape
    return coeffs


def eval_sh_dirs(coeffs: torch.Tensor, dirs: torch.Tensor) -> torch.Tensor:
    """SH functions coeffs (N, K, C) at directions dirs (D, 3) -> values (N, D, C) (no 3DGS 0.5 offset)."""
    degree = math.isqrt(coeffs.shape[1]) - 1
    assert coeffs.dim() == 3 and num_coeffs(degree) == coeffs.shape[1] and dirs.shape[-1] == 3, coeffs.shape
    Y = sh_basis(degree, dirs.to(coeffs.dtype))  # (D, K)
    return torch.einsum("dk,nkc->ndc", Y, coeffs)


def psnr(a: torch.Tensor, b: torch.Tensor, peak: float = 1.0) -> float:
    """PSNR in dB of two same-shape tensors (``peak`` the signal's range); inf when they are equal."""
    assert a.shape == b.shape, (a.shape, b.shape)
    mse = float(((a.double() - b.double()) ** 2).mean())
    return math.inf if mse == 0.0 else 10.0 * math.log10(peak * peak / mse)


__all__ = ["SH_DEGREE", "eval_sh_dirs", "fibonacci_sphere", "fit_sh", "held_out_directions", "psnr"]
