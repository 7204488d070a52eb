"""MaterialFormer and MatDetokenizer (paper Sec. 4.2.1, the T_all / T_mat / G_mat equations; supplement "Model and
training details").

    T_all_i = T_geo_i (+) T_app_i                                  channel concatenation per token
    T_mat_i = MaterialFormer(T_all_i | T_prior_i)                  Pre-LN transformer, GeLU (paper: 4 layers, 1024)
    G_mat_i = MatDetokenizer(T_mat_i)                              single linear layer -> p*p Gaussians per token

Sequence: one object's tokens of all views in one sequence (full self-attention across views, like the backbone):
the coarse tokens (V*h*w, one per patch) followed by the fine tokens (V*M, from
:mod:`frng.model.fine_geometry`; "the input tokens of MaterialFormer can be either coarse-grained or fine-grained",
with T_app and T_prior interpolated like T_geo). Every token, coarse or fine, stands for p*p Gaussians (coarse: the
patch's pixels; fine: its sub-pixel grid) in the patchify order y*p + x, so the MatDetokenizer is shared.
No positional encoding is added: the backbone's tokens already carry their pose (Pluecker rays) in T_geo.

Prior conditioning (our choice): per token, additively in the input embedding,
``x = Linear([T_geo (+) T_app]) + Linear(T_prior)``, which equals one linear layer over
``[T_geo (+) T_app (+) T_prior]`` but lets ``prior_dim = 0`` (the ``no-idm`` ablation) build a model with NO prior
path at all -- it has no parameters for priors and refuses prior tokens, so it can never read them. Appending prior
tokens to the sequence would double the attention cost for no stated benefit.

Heads: ``neural`` (default) -> ``feature_dim`` neural material features per Gaussian, unconstrained (the universal
decoder's input); ``pbr`` (the ``no-neural`` ablation) -> Cook-Torrance parameters per Gaussian via
:func:`decode_pbr`: albedo 3, roughness 1, metallic 1 (sigmoids into bounded ranges, ``frng.render.shading.GGX_*``),
normal 3 (unit, world frame).

Attention uses :func:`torch.nn.functional.scaled_dot_product_attention` (via :mod:`frng.nn`); everything runs under
``torch.autocast(..., dtype=torch.bfloat16)`` (LayerNorms and the loss run in fp32 there).
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import nn

from frng.nn import Transformer, unpatchify
from frng.plan.sections import Settings
from frng.render.shading import GGX_MAX_METALLIC, GGX_MIN_ALBEDO, GGX_MIN_ROUGHNESS

PBR_CHANNELS = 8  # albedo 3, roughness 1, metallic 1, normal 3
MIN_ROUGHNESS = GGX_MIN_ROUGHNESS


@dataclass
class MaterialFormerConfig(Settings):
    """MaterialFormer / MatDetokenizer sizes (proposed config section ``model.materialformer``)."""

    geo_dim: int = 256  # width of T_geo (the backbone's)
    app_dim: int = 256  # width of T_app (the backbone's)
    prior_dim: int = 64  # width of T_prior; 0 = no priors (no-idm)
    hidden: int = 256  # paper 1024
    depth: int = 4  # paper 4
    heads: int = 4
    mlp_ratio: float = 4.0
    patch: int = 8
    feature_dim: int = 16  # neural material features per Gaussian
    head: str = "neural"  # "neural" | "pbr" (no-neural ablation)

    def __post_init__(self):
        if self.head not in ("neural", "pbr"):
            raise ValueError(f"materialformer.head must be 'neural' or 'pbr', got {self.head!r}")

    @property
    def out_channels(self) -> int:
        return self.feature_dim if self.head == "neural" else PBR_CHANNELS


class MaterialFormer(nn.Module):
    """(T_geo, T_app | T_prior) -> T_mat.

    forward: t_geo (B, L, geo_dim), t_app (B, L, app_dim), t_prior (B, L, prior_dim) or None -> T_mat (B, L, hidden)
    (the output of the final LayerNorm; these are the tokens the light-independence loss compares).
    """

    def __init__(self, cfg: MaterialFormerConfig | None = None):
        super().__init__()
        self.cfg = cfg = cfg or MaterialFormerConfig()
        self.in_proj = nn.Linear(cfg.geo_dim + cfg.app_dim, cfg.hidden)
        self.prior_proj = nn.Linear(cfg.prior_dim, cfg.hidden) if cfg.prior_dim > 0 else None
        self.transformer = Transformer(cfg.hidden, cfg.depth, cfg.heads, cfg.mlp_ratio)

    @property
    def uses_priors(self) -> bool:
        return self.prior_proj is not None

    def forward(self, t_geo: torch.Tensor, t_app: torch.Tensor, t_prior: torch.Tensor | None = None) -> torch.Tensor:
        if t_geo.shape[:-1] != t_app.shape[:-1]:
            raise ValueError(f"T_geo {tuple(t_geo.shape)} and T_app {tuple(t_app.shape)} differ in tokens")
        x = self.in_proj(torch.cat([t_geo, t_app], dim=-1))
        if self.prior_proj is not None:
            if t_prior is None:
                raise ValueError("MaterialFormer was built with priors (prior_dim > 0) but got none")
            x = x + self.prior_proj(t_prior)
        elif t_prior is not None:
            raise ValueError("MaterialFormer was built without priors (prior_dim = 0, no-idm) but got prior tokens")
        return self.transformer(x)


class MatDetokenizer(nn.Module):
    """G_mat = Linear(T_mat): (..., hidden) -> (..., p*p, out_channels), Gaussians in patchify order y*p + x."""

    def __init__(self, hidden: int, out_channels: int, patch: int = 8):
        super().__init__()
        self.patch, self.out_channels = patch, out_channels
        self.proj = nn.Linear(hidden, patch * patch * out_channels)

    def forward(self, t_mat: torch.Tensor) -> torch.Tensor:
        out = self.proj(t_mat)
        return out.reshape(*out.shape[:-1], self.patch * self.patch, self.out_channels)


def decode_pbr(raw: torch.Tensor) -> dict[str, torch.Tensor]:
    """``no-neural`` head output (..., 8) -> Cook-Torrance parameters per Gaussian.

    Returns albedo (..., 3) in [GGX_MIN_ALBEDO, 1], roughness (..., 1) in [GGX_MIN_ROUGHNESS, 1], metallic (..., 1)
    in [0, GGX_MAX_METALLIC], normal (..., 3) unit (world frame; a zero vector maps to +Z). The bounds keep every
    logit, however extreme, from switching a lit surface off (a black base colour, a pure metal without a diffuse
    lobe, a near-delta specular lobe).
    """
    raw = raw.float()
    albedo = GGX_MIN_ALBEDO + (1.0 - GGX_MIN_ALBEDO) * torch.sigmoid(raw[..., 0:3])
    roughness = GGX_MIN_ROUGHNESS + (1.0 - GGX_MIN_ROUGHNESS) * torch.sigmoid(raw[..., 3:4])
    metallic = GGX_MAX_METALLIC * torch.sigmoid(raw[..., 4:5])
    n = raw[..., 5:8]
    norm = n.norm(dim=-1, keepdim=True)
    up = torch.zeros_like(n)
    up[..., 2] = 1.0
    normal = torch.where(norm > 1e-8, n / norm.clamp_min(1e-8), up)
    return {"albedo": albedo, "roughness": roughness, "metallic": metallic, "normal": normal}


class MaterialHead(nn.Module):
    """MaterialFormer + MatDetokenizer, the trainable appearance-distillation network of F-RNG.

    forward(t_geo (B, L, geo_dim), t_app (B, L, app_dim), t_prior (B, L, prior_dim) | None)
    -> (T_mat (B, L, hidden), G_mat (B, L, p*p, out_channels)); use :func:`decode_pbr` on G_mat for ``head='pbr'``.
    """

    def __init__(self, cfg: MaterialFormerConfig | None = None):
        super().__init__()
        self.cfg = cfg = cfg or MaterialFormerConfig()
        self.former = MaterialFormer(cfg)
        self.detokenizer = MatDetokenizer(cfg.hidden, cfg.out_channels, cfg.patch)

    def forward(self, t_geo, t_app, t_prior=None):
        t_mat = self.former(t_geo, t_app, t_prior)
        return t_mat, self.detokenizer(t_mat)


def to_sequence(coarse: torch.Tensor, fine: torch.Tensor | None = None) -> torch.Tensor:
    """Build MaterialFormer's input sequence from token grids.

    coarse: (V, h, w, D) or (B, V, h, w, D); fine: (V, M, D) or (B, V, M, D) or None.
    Returns (B, V*h*w [+ V*M], D) (B = 1 if unbatched): coarse tokens in (view, row, col) order, then fine tokens
    in (view, token) order.
    """
    if coarse.dim() == 4:
        coarse = coarse.unsqueeze(0)
        fine = None if fine is None else fine.unsqueeze(0)
    B, D = coarse.shape[0], coarse.shape[-1]
    parts = [coarse.reshape(B, -1, D)]
    if fine is not None:
        parts.append(fine.reshape(B, -1, D))
    return torch.cat(parts, dim=1)


def split_sequence(seq: torch.Tensor, views: int, h: int, w: int) -> tuple[torch.Tensor, torch.Tensor]:
    """Inverse of :func:`to_sequence` for per-token outputs: seq (B, V*h*w + V*M, ...) ->
    coarse (B, V, h, w, ...), fine (B, V, M, ...)."""
    B, L = seq.shape[:2]
    rest = seq.shape[2:]
    nc = views * h * w
    if (L - nc) % views:
        raise ValueError(f"sequence of {L} tokens does not hold {views} views of {h}x{w} coarse + equal fine tokens")
    coarse = seq[:, :nc].reshape(B, views, h, w, *rest)
    fine = seq[:, nc:].reshape(B, views, (L - nc) // views, *rest)
    return coarse, fine


def coarse_features_to_pixels(features: torch.Tensor, patch: int) -> torch.Tensor:
    """Per-Gaussian features of the coarse tokens (..., h, w, p*p, F) -> per pixel (..., H, W, F), i.e. aligned with
    the backbone's per-pixel Gaussians (:func:`frng.gaussians.pixel_gaussians` order)."""
    *lead, h, w, P, Fd = features.shape
    return unpatchify(features.reshape(*lead, h, w, P * Fd), patch, Fd)


def kept_rows(keep_coarse: torch.Tensor, keep_fine: torch.Tensor | None, views: int, h: int, w: int, patch: int):
    """Rows of a per-token output flattened to (L * P, C) (:func:`to_sequence` order, P = patch^2 Gaussians per
    coarse token) that hold the kept Gaussians' features: first the kept coarse pixels in pixel order (what
    ``coarse_features_to_pixels(split_sequence(.)[0]).reshape(-1, C)[keep_coarse]`` reads), then the kept fine
    Gaussians (``split_sequence(.)[1].reshape(-1, C)[keep_fine]``). One ``index_select`` with these rows replaces
    the slice, the unpatchify permutation and the two mask gathers (and their backward's full-size zero fills).

    keep_coarse (V * H * W,) bool, H = h * patch; keep_fine (V * M * P,) bool or None. Returns (N_kept,) int64."""
    H, W, P = h * patch, w * patch, patch * patch
    assert keep_coarse.shape == (views * H * W,), (keep_coarse.shape, views, H, W)
    n = keep_coarse.nonzero()[:, 0]
    v, yx = n // (H * W), n % (H * W)
    y, x = yx // W, yx % W
    rows = ((v * h + y // patch) * w + x // patch) * P + (y % patch) * patch + x % patch
    if keep_fine is None:
        return rows
    return torch.cat([rows, views * h * w * P + keep_fine.nonzero()[:, 0]])


__all__ = [
    "MIN_ROUGHNESS",
    "PBR_CHANNELS",
    "MatDetokenizer",
    "MaterialFormer",
    "MaterialFormerConfig",
    "MaterialHead",
    "coarse_features_to_pixels",
    "decode_pbr",
    "kept_rows",
    "split_sequence",
    "to_sequence",
]
