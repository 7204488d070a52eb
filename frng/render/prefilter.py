"""Prefiltered environment maps: the closed-form specular base of the cosine decoder (``shading.decoder_specular``),
and its other model, a GGX lobe estimated by Monte Carlo with the decoder's residual (:func:`with_ggx_specular`,
``shading.specular_model: ggx``).

The cosine decoder's Lambertian base (:func:`frng.render.shading.lambert_sh`) relights the diffuse part of every
surface without Monte-Carlo noise; a glossy surface's highlight is the environment seen in the mirror direction,
blurred by the surface's roughness, which 16-32 light samples drawn by the map's luminance estimate with a large
variance (the samples rarely fall inside a narrow lobe). This module gives that term in closed form, as real-time
renderers do ("split sum", Karis 2013): the map convolved with a von Mises-Fisher lobe of sharpness kappa at a few
levels, looked up at the reflected direction and interpolated between levels by a per-pixel roughness:

    S(p) = k_s(p) L_kappa(p)(r),   r = 2 (n . w_o) n - w_o,   L_kappa(w) = int L(w') vMF_kappa(w . w') dw'

with k_s (specular colour) and the level (roughness) read from the decoder's feature channels 6:10
(:func:`specular_params`, :func:`specular_base`). Shapes: env maps (He, We, 3) linear HDR, equirect in
:mod:`frng.render.envmap`'s convention.

Parameterisations (``shading.specular_param``):

- ``linear`` (default): k_s = softplus(G (f - f0)) / G with G = :data:`SPECULAR_GAIN`, i.e. ~max(f - f0, 0) with a
  smooth floor, 0.02 at f = 0 (slope 0.33 there, 1 above ~0.1): the same scale as the diffuse channels 3:6, so a
  training step moves k_s as far as it moves the albedo; level = (L - 1) sigmoid(4 f_9) (1.5 at f = 0).
- ``softplus`` (models saved before the key existed): k_s = softplus(f - 4) (0.018 at f = 0, slope 0.018), level =
  (L - 1) sigmoid(f_9). Measured on the 856109f reproduction's full model: k_s stayed at 0.022-0.026 on EVERY
  pixel of every object (metal, glossy dielectric and diffuse alike): Adam moves a feature by ~lr per step, and
  k_s = 0.5 needs f ~ 4.5 (or ~0 needs f ~ -4), so the base stayed the constant haze it started as.

With ``linear`` the default-tier training turns the base almost off instead (k_s median 0.006, level 2.7: the
broadest lobes), which scored +0.06 / +0.10 dB over ``softplus`` with training seeds 0 / 1 (README, "F-RNG model");
trained on glossy objects alone it carries half of their light. Highlights need normals good enough to place them.
"""

from __future__ import annotations

import functools
import math
import weakref

import torch
import torch.nn.functional as F

from frng.render import envmap
from frng.render.shading import GGX_MIN_ROUGHNESS, SPECULAR_PARAMS, face_forward, ggx_reflectance

KAPPAS = (400.0, 100.0, 25.0, 6.0)  # lobe sharpness per level: ~3, 6, 11, 23 degrees (1 / sqrt(kappa) rad)
PREFILTER_HEIGHT = 32  # maps are area-averaged to 32 x 64 before convolving (texel ~5.6 degrees)
SPECULAR_CHANNELS = slice(6, 10)  # decoder features: 6:9 specular colour logits, 9 level logit
SPECULAR_OFFSET = 4.0  # softplus: k_s = softplus(f - 4): ~0.018 at a zero feature (almost Lambertian)
SPECULAR_GAIN = 20.0  # linear: k_s = softplus(G (f - f0)) / G, ~max(f - f0, 0) with a floor ~1 / G wide
SPECULAR_F0 = 0.035  # linear: softplus(-G f0) / G = 0.020 at f = 0 (as softplus starts: almost Lambertian)
LEVEL_GAIN = 4.0  # linear: level = (L - 1) sigmoid(4 f_9): a feature step of ~1 spans the levels


@functools.lru_cache(maxsize=4)
def lobe_weights(kappas: tuple[float, ...], height: int, device: str) -> tuple[torch.Tensor, ...]:
    """The normalised vMF weights (T, T) per kappa, T = height * 2 height texels: they depend on the texel grid
    alone, so they are computed once per (kappas, height, device) and reused for every map (a training step
    prefilters its target light: this was ~15% of a default-tier step). 4 x 2048^2 float32 = 64 MB."""
    dev = torch.device(device)
    d = envmap.pixel_directions(height, 2 * height, device=dev, dtype=torch.float32).reshape(-1, 3)
    omega = envmap.pixel_solid_angles(height, 2 * height, device=dev, dtype=torch.float32).reshape(-1)
    cos = d @ d.T  # (T, T)
    out = []
    for k in kappas:
        w = torch.exp(k * (cos - 1.0)) * omega[None]
        out.append(w / w.sum(-1, keepdim=True))
    return tuple(out)


def convolve(env: torch.Tensor, kappas: tuple[float, ...] = KAPPAS, height: int = PREFILTER_HEIGHT) -> torch.Tensor:
    """:func:`prefilter`'s convolution, differentiable and not memoised (a light being optimised, e.g. the gsir
    baseline's): env (He, We, 3) area-averaged to height x 2 height and convolved with the normalised vMF lobes ->
    (L, height, 2 height, 3)."""
    e = F.adaptive_avg_pool2d(env.float().permute(2, 0, 1)[None].clamp_min(0.0), (height, 2 * height))[0]
    e = e.permute(1, 2, 0).reshape(-1, 3)
    weights = lobe_weights(tuple(float(k) for k in kappas), int(height), str(e.device))
    return torch.stack([(w @ e).reshape(height, 2 * height, 3) for w in weights])


def prefilter(env: torch.Tensor, kappas: tuple[float, ...] = KAPPAS, height: int = PREFILTER_HEIGHT) -> torch.Tensor:
    """env (He, We, 3) -> (L, height, 2 height, 3): the map convolved with normalised vMF lobes of each kappa
    (dense over the texels; L = len(kappas)), sharpest first, on env's device. No gradient (the light is data).

    Memoised per env tensor (:data:`_PREFILTERED`): a training run shades its objects' few target maps thousands of
    times and a relighting job every run under the same maps; the dense convolution was ~5% of a default-tier
    training step. A hit needs the same tensor object, unmodified since (its in-place version counter)."""
    assert env.ndim == 3 and env.shape[-1] == 3, env.shape
    key = (id(env), tuple(float(k) for k in kappas), int(height))
    hit = _PREFILTERED.get(key)
    if hit is not None and hit[0]() is env and hit[1] == env._version:
        return hit[2]
    with torch.no_grad():
        out = convolve(env.detach(), key[1], key[2])
    if len(_PREFILTERED) >= _PREFILTERED_MAX:
        _PREFILTERED.clear()
    _PREFILTERED[key] = (weakref.ref(env), env._version, out)
    return out


# (id(env), kappas, height) -> (weak reference to env, env._version then, prefiltered map): a dead reference or a
# new version is a miss (an id can be reused after its tensor is freed). <= 256 x ~100 kB at the default sizes.
_PREFILTERED: dict[tuple, tuple[weakref.ref, int, torch.Tensor]] = {}
_PREFILTERED_MAX = 256


def lookup(pref: torch.Tensor, dirs: torch.Tensor, level: torch.Tensor) -> torch.Tensor:
    """Prefiltered radiance (P, 3) at unit directions dirs (P, 3) and fractional levels level (P,) in [0, L-1]
    (bilinear within a level, wrapping in longitude; linear between levels; differentiable in dirs and level)."""
    L, h, w, _ = pref.shape
    u, v = envmap.dir_to_uv(dirs.float())
    # wrap in u: pad one column on each side
    padded = torch.cat([pref[:, :, -1:], pref, pref[:, :, :1]], 2).permute(0, 3, 1, 2)  # (L, 3, h, w + 2)
    x = (u * w + 1.0) / (w + 2) * 2.0 - 1.0
    y = v * 2.0 - 1.0
    grid = torch.stack([x, y], -1).reshape(1, 1, -1, 2).expand(L, 1, -1, 2).to(pref.dtype)
    vals = F.grid_sample(padded, grid, mode="bilinear", padding_mode="border", align_corners=False)  # (L, 3, 1, P)
    vals = vals[:, :, 0].permute(2, 0, 1)  # (P, L, 3)
    lv = level.float().clamp(0, L - 1)
    i0 = lv.floor().long().clamp(max=L - 1)
    i1 = (i0 + 1).clamp(max=L - 1)
    t = (lv - i0.float())[:, None]
    a = vals.gather(1, i0[:, None, None].expand(-1, 1, 3))[:, 0]
    b = vals.gather(1, i1[:, None, None].expand(-1, 1, 3))[:, 0]
    return a * (1.0 - t) + b * t


# the same maps as text, for a model's decoder description (asset.json "output"): (k_s, level) per parameterisation
SPECULAR_FORMULAS = {
    "linear": ("softplus(20 (feature[6:9] - 0.035)) / 20", "3 sigmoid(4 feature[9])"),
    "softplus": ("softplus(feature[6:9] - 4)", "3 sigmoid(feature[9])"),
}


def specular_params(f: torch.Tensor, levels: int, param: str = "linear") -> tuple[torch.Tensor, torch.Tensor]:
    """Unpremultiplied features f (P, C >= 10) -> (k_s (P, 3) >= 0, level (P,) in [0, levels - 1]) under the
    parameterisation ``param`` (module docstring; ``shading.specular_param``)."""
    assert f.shape[-1] >= 10, f.shape
    if param == "linear":
        ks = F.softplus(SPECULAR_GAIN * (f[:, 6:9] - SPECULAR_F0)) / SPECULAR_GAIN
        return ks, (levels - 1) * torch.sigmoid(LEVEL_GAIN * f[:, 9])
    if param == "softplus":
        return F.softplus(f[:, 6:9] - SPECULAR_OFFSET), (levels - 1) * torch.sigmoid(f[:, 9])
    raise ValueError(f"shading.specular_param must be one of {SPECULAR_PARAMS}, got {param!r}")


def with_ggx_specular(residual, param: str = "linear"):
    """The cosine decoder's Monte-Carlo reflectance with the specular base as a GGX lobe (``shading.specular_model:
    ggx``): ``reflectance(features (P, C >= 10), wo (P, 3), wi (K, 3)) -> (P, K, 3)`` = ``residual(features, wo,
    wi)`` + the Cook-Torrance specular lobe x cosine (:func:`frng.render.shading.ggx_reflectance`, specular only)
    with F0 = k_s (features 6:9, :func:`specular_params` under ``param``, clamped to [0, 1]), roughness = the level
    of :func:`specular_params` with two levels, in [0, 1] (>= ``GGX_MIN_ROUGHNESS``; 0.5 at f_9 = 0) and the normal
    of features 0:3 turned to face the camera (:func:`frng.render.shading.face_forward`, as the Cook-Torrance
    ablation's). Unlike the prefiltered lookup it sees the light samples, so it keeps Fresnel, shadowing-masking and
    the lobe's shape; it costs one more term in the residual's Monte-Carlo pass. Measured (README "Results"):
    +0.09 dB [0.04, 0.14] over the prefiltered base, training seeds 0 and 1."""

    def reflectance(features: torch.Tensor, wo: torch.Tensor, wi: torch.Tensor) -> torch.Tensor:
        out = residual(features, wo, wi)
        f = features.float()
        ks, level = specular_params(f, 2, param)
        rough = level[:, None].clamp(GGX_MIN_ROUGHNESS, 1.0)
        n = face_forward(f[:, :3], wo.float())
        spec = ggx_reflectance(ks.clamp(0.0, 1.0), rough, torch.ones_like(rough), n, wo.float(), wi.float(), False)
        return out + spec.to(out.dtype)

    return reflectance


def specular_split(residual, shading, specular: bool):
    """Where the cosine decoder's specular base goes under ``shading.specular_model`` (``shading``: a
    :class:`frng.render.shading.ShadingConfig`; ``specular``: the decoder has a base, ``shading.decoder_specular``).
    Returns (the reflectance the Monte-Carlo pass integrates: ``residual``, or :func:`with_ggx_specular` of it,
    whether the closed-form prefiltered base (:func:`specular_at_cameras`) is added after that pass)."""
    if specular and shading.specular_model == "ggx":
        return with_ggx_specular(residual, shading.specular_param), False
    return residual, specular


def specular_base(
    maps: torch.Tensor,
    alpha: torch.Tensor,
    pref: torch.Tensor,
    view_dirs: torch.Tensor,
    alpha_eps: float = 1e-3,
    param: str = "linear",
) -> torch.Tensor:
    """The specular base S (V, H, W, 3), premultiplied by alpha, of the decoder's rasterized features.

    maps (V, H, W, C >= 10) alpha-premultiplied features (0:3 normal n, 6:9 specular colour logits, 9 level logit);
    alpha (V, H, W, 1); pref from :func:`prefilter`; view_dirs (V, H, W, 3) unit camera rays (camera -> surface).
    k_s and the level from :func:`specular_params` (``param``); zero where alpha <= alpha_eps."""
    assert maps.shape[:3] == alpha.shape[:3] == view_dirs.shape[:3] and maps.shape[-1] >= 10, (maps.shape,)
    fg = alpha[..., 0] > alpha_eps
    out = torch.zeros(*maps.shape[:3], 3, device=maps.device, dtype=torch.float32)
    if not bool(fg.any()):
        return out
    a = alpha[fg].float()
    f = maps[fg].float() / a.clamp_min(alpha_eps)
    n = F.normalize(f[:, :3], dim=-1, eps=1e-6)
    wo = -view_dirs[fg].float()
    r = F.normalize(2.0 * (n * wo).sum(-1, keepdim=True) * n - wo, dim=-1, eps=1e-6)
    ks, level = specular_params(f, pref.shape[0], param)
    s = ks * lookup(pref, r, level) * a
    return out.index_put(torch.nonzero(fg, as_tuple=True), s)


def specular_at_cameras(
    maps: torch.Tensor,
    alpha: torch.Tensor,
    c2w: torch.Tensor,
    intr: torch.Tensor,
    env: torch.Tensor,
    alpha_eps: float = 1e-3,
    param: str = "linear",
) -> torch.Tensor:
    """:func:`specular_base` of rasterized maps (V, H, W, C) seen by cameras c2w (V, 4, 4), intr (V, 4) under an
    env map (He, We, 3): the view rays and the (memoised) prefiltered map made here. The one entry point of both
    renderers (:meth:`frng.model.composed.FRNG.specular`, :class:`frng.apps.asset.AssetRenderer`)."""
    from frng import camera

    _, d = camera.pixel_rays(c2w.float(), intr.float(), maps.shape[1], maps.shape[2])
    return specular_base(maps, alpha, prefilter(env).to(maps.device), d, alpha_eps, param)


def vmf_lobe_mean(kappa: float) -> float:
    """Mean cosine of a vMF lobe (its angular width): coth(kappa) - 1 / kappa (tests, documentation)."""
    return 1.0 / math.tanh(kappa) - 1.0 / kappa


__all__ = [
    "KAPPAS",
    "PREFILTER_HEIGHT",
    "SPECULAR_CHANNELS",
    "SPECULAR_FORMULAS",
    "SPECULAR_PARAMS",
    "lookup",
    "prefilter",
    "specular_at_cameras",
    "specular_base",
    "specular_params",
    "specular_split",
    "vmf_lobe_mean",
    "with_ggx_specular",
]
