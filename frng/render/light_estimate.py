"""The input light, estimated from the photos: what every test-time path uses where a light is needed for the
input views, since the paper's task gives none (the photos' light is unknown; only the target light is given).

:func:`estimate_light_sh` fits a degree-2 SH radiance L (9, 3) to the shading of the foreground pixels: shading =
colour / albedo = E(n) / pi, with the albedo and world normals from the intrinsic-decomposition priors (or a
constant albedo and the geometry's normals where a model has no priors). The fit is ridge-regularised least squares:
the l >= 1 bands are damped towards 0 so the directions no photo sees stay dim. Light colour and albedo colour are
ambiguous (a green object under white light or a white one under green light): ``colour='neutral'`` (the default)
makes the fitted light grey on average (each channel scaled so its DC term has the DC luminance; grey world).
Users: ``frng reconstruct`` (:func:`frng.apps.capture.estimate_light` expands it into a map) and F-RNG+'s pixel head
(:func:`frng.model.pixel_head.pixel_map`), at training and at test time alike.
"""

from __future__ import annotations

import math

import torch

from frng.render import envmap

LIGHT_COLOURS = ("neutral", "fit")
MIN_PIXELS = 16  # fewer confident foreground pixels: no estimate (LightEstimateError)


class LightEstimateError(ValueError):
    """Too few confident foreground pixels to fit the light, or an unknown option."""


def estimate_light_sh(
    rgb: torch.Tensor,
    alpha: torch.Tensor,
    albedo: torch.Tensor,
    normal: torch.Tensor,
    ridge: float = 0.1,
    colour: str = "neutral",
) -> tuple[torch.Tensor, dict]:
    """Degree-2 SH radiance of the input light from the photos (module docstring).

    rgb (..., 3) linear premultiplied, alpha (..., 1), albedo (..., 3) (priors, or a constant), normal (..., 3) world
    normals (zero = none); any leading shape (e.g. (V, H, W)). Uses the confident foreground: alpha > 0.9, albedo
    mean > 0.02, a normal. Returns (coefficients (9, 3) float64 on the CPU, info: method, ridge, colour, pixels,
    relative_rms). Raises :class:`LightEstimateError` with fewer than :data:`MIN_PIXELS` such pixels."""
    from frng.render.sh import sh_basis

    if colour not in LIGHT_COLOURS:
        raise LightEstimateError(f"light colour {colour!r}: choose one of {', '.join(LIGHT_COLOURS)}")

    def flat(x: torch.Tensor) -> torch.Tensor:
        x = torch.as_tensor(x)
        return x.detach().to("cpu", torch.float64).reshape(-1, x.shape[-1])

    rgb, a, alb, n = flat(rgb), flat(alpha), flat(albedo), flat(normal)
    nn_ = n.norm(dim=-1, keepdim=True)
    fg = (a[:, 0] > 0.9) & (alb.mean(-1) > 0.02) & (nn_[:, 0] > 0.5)
    if int(fg.sum()) < MIN_PIXELS:
        raise LightEstimateError(
            f"light estimation: too few confident foreground pixels ({int(fg.sum())} < {MIN_PIXELS})"
        )
    s = (rgb[fg] / a[fg]) / alb[fg].clamp_min(0.03)
    Y = sh_basis(2, n[fg] / nn_[fg])
    band = Y.new_tensor(
        [envmap.SH_IRRADIANCE_BANDS[0]] + [envmap.SH_IRRADIANCE_BANDS[1]] * 3 + [envmap.SH_IRRADIANCE_BANDS[2]] * 5
    )
    A = Y * band / math.pi
    P = A.shape[0]
    reg = torch.diag(A.new_tensor([0.0] + [ridge] * 8)) * P
    L = torch.linalg.solve(A.T @ A + reg, A.T @ s)  # (9, 3)
    if colour == "neutral":  # grey world: the light's mean colour is grey (same luminance), the albedo keeps the rest
        dc = L[0].clamp_min(1e-9)
        L = L * (envmap.luminance(dc) / dc)[None]
    resid = float(((A @ L - s) ** 2).mean().sqrt() / s.mean().clamp_min(1e-9))
    info = {"method": "sh2-ridge", "ridge": ridge, "colour": colour, "pixels": int(P), "relative_rms": resid}
    return L, info


def sh_to_env(coeffs: torch.Tensor, height: int) -> torch.Tensor:
    """A degree-2 SH radiance (9, 3) expanded into an equirect map (height, 2 height, 3) float32, negative lobes
    clamped to 0."""
    from frng.render.sh import sh_basis

    d = envmap.pixel_directions(height, 2 * height, dtype=torch.float64)
    return (sh_basis(2, d) @ coeffs.double()).clamp_min(0.0).float()


__all__ = ["LIGHT_COLOURS", "LightEstimateError", "estimate_light_sh", "sh_to_env"]
