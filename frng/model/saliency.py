"""Saliency map and top-K salient patch selection (supplement, "Saliency map computation"; paper Sec. 4.1).

Per input view (all steps in pixels of that view)::

    I_gray      = luminance of the view (Rec. 709 weights), optionally tone-mapped (see below)
    mu          = BoxFilter(I_gray, beta)
    mu_square   = BoxFilter(I_gray^2, beta)
    S_raw       = sqrt(max(mu_square - mu^2, 0))                       local standard deviation
    D           = Euclidean distance of each foreground pixel to the nearest background pixel (0 on background)
    W_linear    = Clamp(Normalize(D), 0, 1),  Normalize(D) = (D - margin) / ramp
    W           = GaussianBlur(W_linear, sigma)
    S_final     = S_raw * W

Patch score = mean of ``S_final`` over the patch's p x p pixels. Per view the ``ceil(K * h * w)`` patches with the
highest scores are selected (paper: K = 2%), so every view contributes the same number of fine tokens and the
selection has a fixed shape (V, n).

Choices the paper leaves open (all :class:`SaliencyConfig` fields):

- ``box_size`` (beta): odd box-filter width in pixels; filters use reflect padding at the image border, so the
  border itself creates no saliency.
- ``margin`` (default ``box_size // 2 + 1``): pixels whose box window reaches the background get weight 0 -- that is
  exactly where the silhouette contrast leaks into S_raw; ``ramp``: width in pixels of the linear rise to 1 after it.
- ``sigma``: std (pixels) of the Gaussian blur of ``W_linear`` (kernel radius ``ceil(3 sigma)``, reflect padding).
- ``tonemap``: inputs are linear HDR; by default they are clamped to [0, 1] and gamma-encoded (1/2.2) first so the
  local std measures perceived texture rather than raw radiance (which bright highlights would dominate).
- Foreground: the ``mask`` argument, else the alpha channel of RGBA input (> 0.5), else the whole image (then no
  boundary suppression happens: W = 1).

The distance transform uses ``scipy.ndimage.distance_transform_edt`` on CPU (the map is computed once per object,
without gradients); everything else is torch.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np
import torch
import torch.nn.functional as F
from scipy import ndimage

from frng.plan.sections import key, register

LUMA = (0.2126, 0.7152, 0.0722)  # Rec. 709 on linear RGB


@register("frng.saliency")
@dataclass(frozen=True)
class SaliencyConfig:
    """Saliency / patch-selection parameters: the config's ``frng.saliency`` section (each key declared on its field) plus two internal fields, ``margin`` (not a config key) and ``top_k`` (set from
    ``frng.top_k_percent`` by :meth:`frng.model.composed_config.FRNGConfig.saliency_config`)."""

    box_size: int = key(
        5,
        "box size (beta, odd, pixels) of the saliency map's box filter (frng/model/saliency.py)",
        type="integer",
        minimum=1,
        maximum=255,
    )
    ramp: float = key(
        4.0,
        "pixels over which the saliency weight W rises linearly from 0 to 1 after the margin",
        type="number",
        minimum=0,
    )
    sigma: float = key(
        1.0,
        "Gaussian blur (pixels) of the linear saliency weight",
        type="number",
        minimum=0,
    )
    tonemap: bool = key(
        True,
        "tone-map the image before the saliency map is computed",
        type="boolean",
    )
    margin: float | None = None  # internal: pixels from the background with W = 0; None -> box_size // 2 + 1
    top_k: float = 0.02  # internal: K as a fraction of the patches of one view (paper 2%)

    def __post_init__(self):
        if self.box_size < 1 or self.box_size % 2 == 0:
            raise ValueError(f"saliency.box_size must be a positive odd integer, got {self.box_size}")
        if self.ramp <= 0:
            raise ValueError("saliency.ramp must be > 0")
        if not 0.0 <= self.top_k <= 1.0:
            raise ValueError(f"saliency.top_k is a fraction in [0, 1], got {self.top_k}")

    @property
    def effective_margin(self) -> float:
        return float(self.box_size // 2 + 1) if self.margin is None else float(self.margin)

    def to_dict(self) -> dict:
        return asdict(self)


def _box_filter(x: torch.Tensor, size: int) -> torch.Tensor:
    """(V, H, W) -> (V, H, W) mean over a size x size window, reflect padding (replicate if the image is tiny)."""
    r = size // 2
    if r == 0:
        return x
    mode = "reflect" if min(x.shape[-2:]) > r else "replicate"
    xp = F.pad(x.unsqueeze(1), (r, r, r, r), mode=mode)
    return F.avg_pool2d(xp, size, stride=1).squeeze(1)


def _gaussian_blur(x: torch.Tensor, sigma: float) -> torch.Tensor:
    """(V, H, W) -> (V, H, W) separable Gaussian blur with std ``sigma`` pixels (identity for sigma <= 0)."""
    if sigma <= 0:
        return x
    r = max(1, math.ceil(3.0 * sigma))
    t = torch.arange(-r, r + 1, dtype=x.dtype, device=x.device)
    k = torch.exp(-0.5 * (t / sigma) ** 2)
    k = k / k.sum()
    mode = "reflect" if min(x.shape[-2:]) > r else "replicate"
    y = F.pad(x.unsqueeze(1), (r, r, 0, 0), mode=mode)
    y = F.conv2d(y, k.view(1, 1, 1, -1))
    y = F.pad(y, (0, 0, r, r), mode=mode)
    y = F.conv2d(y, k.view(1, 1, -1, 1))
    return y.squeeze(1)


def grayscale(images: torch.Tensor, tonemap: bool = True) -> torch.Tensor:
    """(V, H, W, C>=3) linear RGB(A) -> (V, H, W) luminance, optionally clamped to [0, 1] and gamma-encoded."""
    w = torch.tensor(LUMA, dtype=images.dtype, device=images.device)
    gray = images[..., :3] @ w
    if tonemap:
        gray = gray.clamp(0.0, 1.0) ** (1.0 / 2.2)
    return gray


def local_std(gray: torch.Tensor, box_size: int) -> torch.Tensor:
    """S_raw: (V, H, W) -> (V, H, W) local standard deviation in a box_size window."""
    mu = _box_filter(gray, box_size)
    mu_sq = _box_filter(gray * gray, box_size)
    return (mu_sq - mu * mu).clamp_min(0.0).sqrt()


def boundary_weight(mask: torch.Tensor, cfg: SaliencyConfig) -> torch.Tensor:
    """W: (V, H, W) bool foreground -> (V, H, W) smooth weight, 0 at/near the silhouette, 1 inside."""
    m = mask.detach().cpu().numpy().astype(bool)
    dist = np.empty(m.shape, dtype=np.float32)
    for v in range(m.shape[0]):
        if m[v].all():  # no background in this view: nothing to suppress
            dist[v] = np.inf
        else:
            dist[v] = ndimage.distance_transform_edt(m[v])
    d = torch.from_numpy(dist).to(device=mask.device, dtype=torch.float32)
    w_linear = ((d - cfg.effective_margin) / cfg.ramp).clamp(0.0, 1.0)
    return _gaussian_blur(w_linear, cfg.sigma)


def foreground_mask(images: torch.Tensor, mask: torch.Tensor | None = None) -> torch.Tensor:
    """(V, H, W) bool foreground: ``mask`` if given, else alpha > 0.5 for RGBA input, else all True."""
    if mask is not None:
        return mask.bool() if mask.dtype == torch.bool else mask > 0.5
    if images.shape[-1] >= 4:
        return images[..., 3] > 0.5
    return torch.ones(images.shape[:-1], dtype=torch.bool, device=images.device)


@torch.no_grad()
def saliency_map(
    images: torch.Tensor, mask: torch.Tensor | None = None, cfg: SaliencyConfig | None = None
) -> torch.Tensor:
    """S_final for every view.

    images: (V, H, W, 3 or 4) linear (premultiplied) RGB or RGBA; mask: (V, H, W) foreground (bool or [0, 1]) or
    None (see :func:`foreground_mask`). Returns (V, H, W) float32, >= 0.
    """
    cfg = cfg or SaliencyConfig.from_dict({})
    images = images.float()
    s_raw = local_std(grayscale(images, cfg.tonemap), cfg.box_size)
    w = boundary_weight(foreground_mask(images, mask), cfg)
    return s_raw * w


def patch_scores(saliency: torch.Tensor, patch: int) -> torch.Tensor:
    """(V, H, W) per-pixel saliency -> (V, h, w) mean per p x p patch."""
    V, H, W = saliency.shape
    if H % patch or W % patch:
        raise ValueError(f"image {H}x{W} is not a multiple of the patch size {patch}")
    return F.avg_pool2d(saliency.unsqueeze(1), patch).squeeze(1)


def num_selected(k: float, num_patches: int) -> int:
    """ceil(K * patches per view), robust to float noise (0.07 * 100 -> 7, not 8)."""
    return min(num_patches, math.ceil(round(k * num_patches, 6)))


def select_top_k(scores: torch.Tensor, k: float) -> torch.Tensor:
    """Top-K% patches per view.

    scores: (V, h, w). Returns (V, n) long flat patch indices ``row * w + col``, n = ceil(k * h * w), ordered by
    descending score (ties: lower index first).
    """
    V, h, w = scores.shape
    n = num_selected(k, h * w)
    flat = scores.reshape(V, h * w)
    # stable descending sort makes ties deterministic (lower flat index first)
    order = torch.sort(flat, dim=1, descending=True, stable=True).indices
    return order[:, :n].contiguous()


def patch_rows_cols(indices: torch.Tensor, w: int) -> tuple[torch.Tensor, torch.Tensor]:
    """(V, n) flat patch indices -> rows (V, n), cols (V, n)."""
    return indices // w, indices % w


def salient_patches(
    images: torch.Tensor, mask: torch.Tensor | None = None, patch: int = 8, cfg: SaliencyConfig | None = None
) -> torch.Tensor:
    """Convenience: images (V, H, W, 3|4) [+ mask (V, H, W)] -> selected flat patch indices (V, n)."""
    cfg = cfg or SaliencyConfig.from_dict({})
    return select_top_k(patch_scores(saliency_map(images, mask, cfg), patch), cfg.top_k)


__all__ = [
    "SaliencyConfig",
    "boundary_weight",
    "foreground_mask",
    "grayscale",
    "local_std",
    "num_selected",
    "patch_rows_cols",
    "patch_scores",
    "saliency_map",
    "salient_patches",
    "select_top_k",
]
