"""The universal neural decoder's deferred shading: the one sequence that training, relighting
(:class:`frng.model.FRNG`) and ``frng render-asset`` (:class:`frng.apps.asset.AssetRenderer`) run.

Beside :mod:`frng.render.shading` (the estimator, the closed-form Lambertian base) and :mod:`frng.render.prefilter`
(the specular base), which it combines.
"""

from __future__ import annotations

import torch
from torch import nn

from frng.render import envmap
from frng.render.envmap import EnvSamples
from frng.render.prefilter import specular_at_cameras, specular_split
from frng.render.shading import ShadingConfig, deferred_shade, lambert_sh


def shade_decoder(
    decoder: nn.Module,
    maps: torch.Tensor,
    alpha: torch.Tensor,
    c2w: torch.Tensor,
    intrinsics: torch.Tensor,
    env: torch.Tensor,
    samples: EnvSamples,
    cfg: ShadingConfig,
    specular: bool,
    spp_grad: int | None = None,
) -> torch.Tensor:
    """The universal neural decoder's deferred shading under an env map: the one sequence :class:`frng.model.FRNG`
    (training, relighting) and :class:`frng.apps.asset.AssetRenderer` (``frng render-asset``) both run.

    A cosine decoder with ``cfg.diffuse == 'sh'`` gets its Lambertian base in closed form (degree-2 SH irradiance of
    ``env``) and Monte Carlo only for its residual, with the specular base (``specular``: the decoder has one) inside
    that pass (``cfg.specular_model: ggx``) or added after it from the prefiltered map (``prefiltered``); with an
    attenuation the sum is clamped at 0 (the attenuated share is an estimate and can overshoot). Any other decoder is
    integrated by Monte Carlo as a whole.

    maps (V, H, W, C) alpha-premultiplied features, alpha (V, H, W, 1), c2w (V, 4, 4), intrinsics (V, 4), env
    (He, We, 3) linear equirect, samples: its light samples. Returns RGB (V, H, W, 3), premultiplied over black."""
    assert maps.shape[:3] == alpha.shape[:3] and alpha.shape[-1] == 1, (maps.shape, alpha.shape)
    assert c2w.shape == (maps.shape[0], 4, 4) and intrinsics.shape == (maps.shape[0], 4), (c2w.shape, intrinsics.shape)
    closed_form = decoder.cosine and cfg.diffuse == "sh"
    reflectance, prefiltered = decoder, False
    if closed_form:
        reflectance, prefiltered = specular_split(decoder.residual, cfg, specular)
    rgb = deferred_shade(
        reflectance,
        [maps],
        alpha,
        c2w,
        intrinsics,
        samples,
        spp_grad,
        cfg.alpha_eps,
        chunk=cfg.chunk_pixels,
        chunk_pairs=cfg.chunk_pairs,
    )
    if not closed_form:
        return rgb
    rgb = rgb.float() + lambert_sh(maps, alpha, envmap.sh_project(env.detach().float().cpu()).float(), cfg.alpha_eps)
    if prefiltered:  # closed-form highlights: the prefiltered map at the mirror direction
        rgb = rgb + specular_at_cameras(maps, alpha, c2w, intrinsics, env, cfg.alpha_eps, cfg.specular_param)
    if decoder.attenuation:
        rgb = rgb.clamp_min(0.0)
    return rgb


__all__ = ["shade_decoder"]
