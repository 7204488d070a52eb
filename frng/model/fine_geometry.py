"""Latent-interpolated fine-grained geometry synthesis (paper Sec. 4.1, the T_fine-geo / T_fine-prior / G_fine-geo
equations).

For the top-K salient patches j of every view (:mod:`frng.model.saliency`)::

    T_fine-geo_j   = Bilinear(T_geo)_j          s*s fine tokens per selected patch
    T_fine-prior_j = Bilinear(T_prior)_j        (and T_fine-app_j = Bilinear(T_app)_j, "interpolated the same way")
    G_fine-geo_j   = FineGeoDetokenizer(T_fine-geo_j | T_fine-prior_j)

Each fine token is decoded into p*p Gaussians placed along sub-pixel rays. The backbone's own GeoDetokenizer keeps
decoding the coarse tokens; the fine Gaussians are extra.

Exact choices (the paper leaves them open):

- Token grid coordinates: token (i, j) of a view sits at the continuous position (row, col) = (i, j), i.e. at its
  patch centre, pixel (x, y) = ((j + 0.5) p, (i + 0.5) p). A continuous position (r, c) corresponds to pixel
  ((c + 0.5) p, (r + 0.5) p).
- Fine positions: with upsampling factor s (``upsample``), patch (i, j) is split into s x s sub-patches of
  (p/s) x (p/s) pixels; sub-patch (a, b) has its centre at (i + (a + 0.5)/s - 0.5, j + (b + 0.5)/s - 0.5)
  (s = 2: offsets +-0.25 patch). Its token is the bilinear interpolation of the 4 surrounding patch tokens
  (same view) at that position; an integer position returns the token exactly (weights 1, 0, 0, 0).
- Border handling: positions are clamped to [0, h-1] x [0, w-1] (replicate padding), so sub-patches on the
  outer half of a border patch take the border token's value along that axis. No interpolation across views.
- Sub-pixel rays: the p*p Gaussians of fine token (i, j, a, b) sit on a regular grid s times denser than pixels
  covering that sub-patch: Gaussian (y, x) of the token (flat index y*p + x, the patchify order) is on the ray
  through pixel coordinate uv = (j p + b p/s + (x + 0.5)/s, i p + a p/s + (y + 0.5)/s), from
  :func:`frng.camera.rays_at` (exact pinhole rays, equal to normalised interpolation of pixel rays).
- FineGeoDetokenizer: LayerNorm on T_fine-geo and (separately) on T_fine-prior, concatenation, one linear layer to
  p*p*9 raw parameters. :meth:`FineGeoDetokenizer.init_from` copies the backbone's GeoDetokenizer (LN + linear)
  into the geometry half and zeros the prior half, so at initialisation the fine decoder is the coarse decoder
  evaluated at interpolated latents. With ``prior_dim = 0`` (``no-idm``) there is no prior input at all.
- Fine scales: decoded with scale offset ``SCALE_OFFSET + ln(s)`` (``scale_shrink``), i.e. a fine Gaussian starts s
  times smaller than a coarse one with the same raw value, matching its s-times denser spacing.
- Fixed shapes: every view has n = ceil(K h w) selected patches, so per view M = n s^2 fine tokens and M p^2 fine
  Gaussians. Fine tokens are ordered (view, selected patch in score order, a, b); fine Gaussians
  (view, fine token, y*p + x).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
from torch import nn

from frng import camera
from frng.gaussians import RAW_CHANNELS, GaussianDecodeConfig, Gaussians, decode_raw
from frng.plan.sections import Settings


@dataclass
class FineGeometryConfig(Settings):
    """Fine-geometry parameters (proposed config section ``model.fine``)."""

    upsample: int = 2  # s: fine tokens per patch = s*s; must divide the patch size
    patch: int = 8
    geo_dim: int = 256  # width of T_geo (the backbone's)
    prior_dim: int = 64  # width of T_prior; 0 = no priors (no-idm)
    scale_shrink: bool = True  # fine scale offset += ln(s)

    def __post_init__(self):
        if self.upsample < 1 or self.patch % self.upsample:
            raise ValueError(f"fine.upsample ({self.upsample}) must be >= 1 and divide the patch size ({self.patch})")


def fine_positions(patch_idx: torch.Tensor, w: int, s: int, dtype=torch.float32) -> torch.Tensor:
    """Continuous token-grid positions of the fine tokens.

    patch_idx: (V, n) flat indices ``row * w + col`` of the selected patches. Returns (V, n*s*s, 2) as (row, col),
    ordered (patch, a, b).
    """
    V, n = patch_idx.shape
    rows = (patch_idx // w).to(dtype)
    cols = (patch_idx % w).to(dtype)
    off = (torch.arange(s, dtype=dtype, device=patch_idx.device) + 0.5) / s - 0.5  # (s,)
    r = rows[:, :, None, None] + off[None, None, :, None]  # (V, n, s, 1)
    c = cols[:, :, None, None] + off[None, None, None, :]  # (V, n, 1, s)
    pos = torch.stack(torch.broadcast_tensors(r, c), dim=-1)  # (V, n, s, s, 2)
    return pos.reshape(V, n * s * s, 2)


def bilinear_tokens(tokens: torch.Tensor, pos: torch.Tensor) -> torch.Tensor:
    """Bilinear interpolation of a token grid at continuous positions, per view, border-clamped.

    tokens: (V, h, w, D); pos: (V, M, 2) as (row, col) in token units (token (i, j) at (i, j)).
    Returns (V, M, D). Integer positions return the tokens exactly.
    """
    V, h, w, D = tokens.shape
    r = pos[..., 0].clamp(0, h - 1)
    c = pos[..., 1].clamp(0, w - 1)
    r0 = r.floor().long()
    c0 = c.floor().long()
    r1 = (r0 + 1).clamp(max=h - 1)
    c1 = (c0 + 1).clamp(max=w - 1)
    fr = (r - r0.to(r.dtype)).unsqueeze(-1).to(tokens.dtype)
    fc = (c - c0.to(c.dtype)).unsqueeze(-1).to(tokens.dtype)
    flat = tokens.reshape(V, h * w, D)

    def gather(ri, ci):
        idx = (ri * w + ci).unsqueeze(-1).expand(-1, -1, D)
        return torch.gather(flat, 1, idx)

    return (
        ((1 - fr) * (1 - fc)) * gather(r0, c0)
        + ((1 - fr) * fc) * gather(r0, c1)
        + (fr * (1 - fc)) * gather(r1, c0)
        + (fr * fc) * gather(r1, c1)
    )


def fine_gaussian_uv(patch_idx: torch.Tensor, w: int, patch: int, s: int, dtype=torch.float32) -> torch.Tensor:
    """Sub-pixel image positions of the fine Gaussians.

    patch_idx: (V, n). Returns uv (V, n*s*s, p*p, 2) as (x, y) pixel coordinates, Gaussian order y*p + x.
    """
    V, n = patch_idx.shape
    p, q = patch, patch // s  # q: pixels per sub-patch side
    dev = patch_idx.device
    rows = (patch_idx // w).to(dtype)
    cols = (patch_idx % w).to(dtype)
    sub = torch.arange(s, dtype=dtype, device=dev) * q  # (s,) sub-patch offsets in pixels
    g = (torch.arange(p, dtype=dtype, device=dev) + 0.5) / s  # (p,) Gaussian offsets inside a sub-patch
    y = (
        rows[:, :, None, None, None, None] * p
        + sub[None, None, :, None, None, None]
        + g[None, None, None, None, :, None]
    )
    x = (
        cols[:, :, None, None, None, None] * p
        + sub[None, None, None, :, None, None]
        + g[None, None, None, None, None, :]
    )
    uv = torch.stack(torch.broadcast_tensors(x, y), dim=-1)  # (V, n, s, s, p, p, 2)
    return uv.reshape(V, n * s * s, p * p, 2)


def sample_pixels(image: torch.Tensor, uv: torch.Tensor, mode: str = "bilinear") -> torch.Tensor:
    """Reads of a per-pixel map at sub-pixel positions (border pixels replicated), bilinear or ``"nearest"`` (the
    value of the pixel containing the position, as :func:`fine_keep_mask` reads the mask).

    image (V, H, W, C); uv (V, M, P, 2) pixel coordinates (x, y), pixel centres at +0.5 -> (V, M, P, C)."""
    from frng.priors.multiview import sample_image

    return sample_image(image, uv, padding="border", mode=mode)


def fine_keep_mask(uv: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    """Foreground test for fine Gaussians, the analogue of the backbone's per-pixel ``keep`` (input alpha > 0.5).

    uv: (V, M, P, 2) sub-pixel positions (x, y); mask: (V, H, W) bool or [0, 1] alpha.
    Returns (V*M*P,) bool: the mask value of the pixel containing each Gaussian's sub-pixel position.
    """
    V, H, W = mask.shape
    m = mask if mask.dtype == torch.bool else mask > 0.5
    x = uv[..., 0].floor().long().clamp(0, W - 1)
    y = uv[..., 1].floor().long().clamp(0, H - 1)
    v = torch.arange(V, device=uv.device).view(V, 1, 1).expand_as(x)
    return m[v, y, x].reshape(-1)


class FineGeoDetokenizer(nn.Module):
    """[LN(T_fine-geo) (+) LN(T_fine-prior)] -> Linear -> p*p raw Gaussian parameters per fine token.

    forward: t_geo (..., geo_dim), t_prior (..., prior_dim) or None (only when prior_dim == 0)
    -> (..., p*p, 9) in patchify order.
    """

    def __init__(self, geo_dim: int, prior_dim: int, patch: int = 8, channels: int = RAW_CHANNELS):
        super().__init__()
        self.geo_dim, self.prior_dim, self.patch, self.channels = geo_dim, prior_dim, patch, channels
        self.norm_geo = nn.LayerNorm(geo_dim)
        self.norm_prior = nn.LayerNorm(prior_dim) if prior_dim > 0 else None
        self.proj = nn.Linear(geo_dim + prior_dim, patch * patch * channels)

    @torch.no_grad()
    def init_from(self, geo_detokenizer: nn.Module) -> FineGeoDetokenizer:
        """Copy a backbone GeoDetokenizer (:class:`frng.nn.PatchDetokenizer`: ``norm`` + ``proj``) into the geometry
        half; zero the prior half. Then the output equals that detokenizer's on the same geometry token."""
        self.norm_geo.load_state_dict(geo_detokenizer.norm.state_dict())
        self.proj.weight.zero_()
        self.proj.weight[:, : self.geo_dim].copy_(geo_detokenizer.proj.weight)
        self.proj.bias.copy_(geo_detokenizer.proj.bias)
        return self

    def forward(self, t_geo: torch.Tensor, t_prior: torch.Tensor | None = None) -> torch.Tensor:
        x = self.norm_geo(t_geo)
        if self.prior_dim > 0:
            if t_prior is None:
                raise ValueError("FineGeoDetokenizer was built with priors (prior_dim > 0) but got none")
            x = torch.cat([x, self.norm_prior(t_prior)], dim=-1)
        elif t_prior is not None:
            raise ValueError("FineGeoDetokenizer was built without priors (prior_dim = 0) but got prior tokens")
        out = self.proj(x)
        return out.reshape(*out.shape[:-1], self.patch * self.patch, self.channels)


@dataclass
class FineGeometryOutput:
    """Result of :class:`FineGeometry` for one object (V views, M = n*s*s fine tokens per view, P = p*p).

    gaussians: N = V*M*P fine Gaussians in (view, token, y*p + x) order (no features);
    raw (V, M, P, 9); uv (V, M, P, 2) sub-pixel positions; pos (V, M, 2) token-grid positions;
    t_geo (V, M, geo_dim), t_prior (V, M, prior_dim) or None: the interpolated fine tokens.
    """

    gaussians: Gaussians
    raw: torch.Tensor
    uv: torch.Tensor
    pos: torch.Tensor
    t_geo: torch.Tensor
    t_prior: torch.Tensor | None


class FineGeometry(nn.Module):
    """Interpolate the selected patches' tokens and decode fine Gaussians along sub-pixel rays (one object).

    forward(t_geo (V, h, w, geo_dim), patch_idx (V, n), c2w (V, 4, 4), intrinsics (V, 4),
            t_prior (V, h, w, prior_dim) or None) -> FineGeometryOutput.
    Appearance tokens: ``interpolate(t_app, patch_idx)`` -> (V, M, D), same positions (call it per light).
    """

    def __init__(self, cfg: FineGeometryConfig | None = None, decode_cfg: GaussianDecodeConfig | None = None):
        super().__init__()
        self.cfg = cfg or FineGeometryConfig()
        base = decode_cfg or GaussianDecodeConfig()
        extra = math.log(self.cfg.upsample) if self.cfg.scale_shrink else 0.0
        self.decode_cfg = GaussianDecodeConfig(
            base.near, base.far, base.scale_offset + extra, base.scale_max, base.opacity_offset
        )
        self.detokenizer = FineGeoDetokenizer(self.cfg.geo_dim, self.cfg.prior_dim, self.cfg.patch)

    def positions(self, patch_idx: torch.Tensor, w: int) -> torch.Tensor:
        """(V, n) -> (V, n*s*s, 2) fine token positions (row, col)."""
        return fine_positions(patch_idx, w, self.cfg.upsample)

    def interpolate(self, tokens: torch.Tensor, patch_idx: torch.Tensor) -> torch.Tensor:
        """Any token grid (V, h, w, D) -> fine tokens (V, n*s*s, D) of the selected patches."""
        return bilinear_tokens(tokens, self.positions(patch_idx, tokens.shape[2]))

    def forward(
        self,
        t_geo: torch.Tensor,
        patch_idx: torch.Tensor,
        c2w: torch.Tensor,
        intrinsics: torch.Tensor,
        t_prior: torch.Tensor | None = None,
        raw_prior: torch.Tensor | None = None,
    ) -> FineGeometryOutput:
        """raw_prior (V, H, W, 9) or None: the backbone's multi-view prior part of its per-pixel raw parameters
        (``BackboneGeometry.raw_prior``); when given, the value of the pixel containing each fine Gaussian's
        sub-pixel position is added to the detokenizer's output, as the backbone adds it to its own (not bilinear:
        at a silhouette that would average the surface's distance with the background's and make floaters)."""
        V, h, w, _ = t_geo.shape
        s, p = self.cfg.upsample, self.cfg.patch
        pos = self.positions(patch_idx, w)
        fine_geo = bilinear_tokens(t_geo, pos)
        fine_prior = None if t_prior is None else bilinear_tokens(t_prior, pos)
        raw = self.detokenizer(fine_geo, fine_prior)  # (V, M, P, 9)
        uv = fine_gaussian_uv(patch_idx, w, p, s)  # (V, M, P, 2)
        if raw_prior is not None:
            raw = raw.float() + sample_pixels(raw_prior.float(), uv, mode="nearest")
        o, d = camera.rays_at(c2w.float(), intrinsics.float(), uv)
        means, quats, scales, opac = decode_raw(raw.float(), o, d, self.decode_cfg)
        g = Gaussians(means.reshape(-1, 3), quats.reshape(-1, 4), scales.reshape(-1, 3), opac.reshape(-1))
        return FineGeometryOutput(g, raw, uv, pos, fine_geo, fine_prior)


__all__ = [
    "FineGeoDetokenizer",
    "FineGeometry",
    "FineGeometryConfig",
    "FineGeometryOutput",
    "bilinear_tokens",
    "fine_gaussian_uv",
    "fine_keep_mask",
    "fine_positions",
    "sample_pixels",
]
