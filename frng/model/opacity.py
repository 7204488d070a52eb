"""Per-Gaussian opacity refinement of the frozen backbone's geometry (our addition; ``frng.opacity_head``).

F-RNG renders the backbone's per-pixel Gaussians (paper Sec. 4.1: the coarse geometry is the frozen backbone's).
With six input views those Gaussians sit on a visual hull that is wider than the object seen from between the
views: slivers outside the true silhouette, blobs around thin parts, and a silhouette about a pixel too wide all
round, which the ground truth's anti-aliased rim shows as a bright ring (at the default tier's 96 px the outermost
ring of the foreground is ~15 % of its pixels and ~45 % of its squared error, for F-RNG and the backbone alike).
The head lets F-RNG change each kept Gaussian's opacity from what F-RNG already knows of it:

    opacity' = sigmoid(logit(opacity) + MLP([g, pixel]))

with ``g`` (N, C_out) the Gaussian's MaterialDetokenizer output (its token's geometry, appearance and prior
context) and ``pixel`` (N, C_pix) its input pixel (:func:`frng.model.pixel_head.pixel_map`: colour, alpha, irradiance,
normals, IDM priors), with ``frng.geometry_inputs`` also the backbone's own geometry at that pixel
(:func:`geometry_inputs`: how far it moved the surface off the hull prior, its raw opacity logit). The last layer
starts at zero: an untrained head keeps the backbone's opacities (clamped to [OPACITY_EPS, 1 - OPACITY_EPS]). It
is trained by F-RNG's own losses through the rasterizer (L_2 on the target's foreground, the perceptual term on the
whole composited image, which sees the slivers outside it).

Two steps, because :meth:`frng.model.composed.FRNG.reconstruct` computes the residual of the input pixels' Gaussians
and applies it after the far-side copies have joined them (each copy takes its source's): :meth:`OpacityHead.residual`
(g (N, C_out), pixel (N, C_pix)) -> (N,) logits, :meth:`OpacityHead.apply` (opacities (M,), logits (M,)) -> (M,)
opacities in (0, 1).
"""

from __future__ import annotations

import torch
from torch import nn

from frng.gaussians import RAW_CHANNELS

# channels of :func:`geometry_inputs`
GEOMETRY_CHANNELS = 2
# logit() of the backbone's opacities is taken at most this close to 0 or 1 (its saturated pixels: opacity 1 would
# give an infinite logit that no residual can move)
OPACITY_EPS = 1e-4


class GaussianResidual(nn.Module):
    """A 2-layer MLP from a Gaussian's detokenizer output and per-Gaussian inputs to one residual per Gaussian; its
    last layer starts at zero (an untrained head changes nothing). :class:`OpacityHead` and
    :class:`frng.model.depth.DepthHead` are two of them."""

    def __init__(self, out_channels: int, pixel_channels: int, hidden: int):
        super().__init__()
        if hidden < 1:
            raise ValueError(f"{type(self).__name__}: hidden must be >= 1, got {hidden}")
        self.in_channels = out_channels + pixel_channels
        self.mlp = nn.Sequential(nn.Linear(self.in_channels, hidden), nn.GELU(), nn.Linear(hidden, 1))
        nn.init.zeros_(self.mlp[-1].weight)
        nn.init.zeros_(self.mlp[-1].bias)

    def residual(self, g: torch.Tensor, pixel: torch.Tensor) -> torch.Tensor:
        """The residual (N,) of N Gaussians: g (N, C_out), pixel (N, C_pix)."""
        assert g.dim() == 2 and pixel.shape[0] == g.shape[0], (g.shape, pixel.shape)
        assert g.shape[1] + pixel.shape[1] == self.in_channels, (g.shape, pixel.shape, self.in_channels)
        return self.mlp(torch.cat([g, pixel.to(g.dtype)], -1))[:, 0]


class OpacityHead(GaussianResidual):
    """A residual on each Gaussian's opacity logit (the module docstring)."""

    @staticmethod
    def apply(opacities: torch.Tensor, residual: torch.Tensor) -> torch.Tensor:
        """opacities (N,) in [0, 1], residual (N,) logits -> sigmoid(logit(opacities) + residual), (N,)."""
        assert opacities.shape == residual.shape, (opacities.shape, residual.shape)
        o = opacities.float().clamp(OPACITY_EPS, 1.0 - OPACITY_EPS)
        return torch.sigmoid(torch.logit(o) + residual.float())


def geometry_inputs(raw: torch.Tensor, raw_prior: torch.Tensor) -> torch.Tensor:
    """The backbone's own geometry per input pixel, the opacity head's extra inputs (``frng.geometry_inputs``):
    raw (V, H, W, 9), raw_prior (V, H, W, 9) (:class:`frng.priors.backbone.BackboneGeometry`) -> (V, H, W, 2) =
    [how far the backbone moved the surface off its multi-view prior (raw distance minus the prior's), its raw
    opacity logit]."""
    assert raw.shape == raw_prior.shape and raw.shape[-1] == RAW_CHANNELS, (raw.shape, raw_prior.shape)
    return torch.stack([raw[..., 0] - raw_prior[..., 0], raw[..., RAW_CHANNELS - 1]], -1)


__all__ = ["GEOMETRY_CHANNELS", "OPACITY_EPS", "GaussianResidual", "OpacityHead", "geometry_inputs"]
