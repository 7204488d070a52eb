"""Image-quality metrics for relighting: PSNR, SSIM, LPIPS (AlexNet, v0.1), with two protocols.

Inputs
------
``pred`` and ``gt`` are float arrays as stored in the EXRs: (H, W, 4) linear, premultiplied RGBA (or (H, W, 3)
RGB, taken as alpha = 1). The foreground ``mask`` is (H, W) bool; by default it is ``gt alpha > 0.5``.

What is compared
----------------
Both images are composited over the configured constant ``background`` (default white, linear (1, 1, 1)) with
their own alpha (:func:`frng.io.composite`), then clipped to [0, 1] and sRGB-encoded with colour-science
(:func:`frng.io.srgb_encode`). Every metric compares these sRGB-encoded [0, 1] RGB images.

Protocols
---------
``aligned`` (default; the relighting literature's protocol: RelitLRM, Neural Gaffer, TensoIR; an unknown input
light leaves a global colour scale ambiguous):

- before compositing, each RGB channel c of the prediction (linear, premultiplied, unclipped) is multiplied by
  the least-squares scale ``s_c = sum_m(p_c * g_c) / sum_m(p_c * p_c)`` over the foreground pixels m of the mask
  (``s_c = 1`` if the prediction is all zero there); alpha is not scaled. The scales are reported
  (``scale_r, scale_g, scale_b``). A least-squares gain is below 1 also when the prediction carries detail that
  is not in the ground truth's places (it shrinks uncorrelated variation), so every protocol also reports the
  ratio of means ``b_c = sum_m(g_c) / sum_m(p_c)`` (``brightness_r, brightness_g, brightness_b``; 1 if the
  prediction is all zero there), which measures only how bright the prediction is;
- PSNR: the MSE is averaged over foreground pixels only (all 3 channels), as RelitLRM / Neural Gaffer do;
  ``psnr_interior`` (a diagnostic beside it, not a protocol): the same over the foreground eroded by
  :data:`RIM_PX` pixels, i.e. without the silhouette's rim, where the geometry's outline decides the error (at the
  default tier's 96 px the 2 px rim is ~20 % of the foreground and ~half of the squared error);
  ``silhouette_iou`` (a diagnostic of the geometry, both protocols): intersection over union of the prediction's
  silhouette (alpha > 0.5) and the mask (:func:`silhouette_iou`);
- SSIM: the SSIM map (see below) averaged over foreground pixels only (the 11x11 windows of pixels near the
  silhouette still overlap the background);
- LPIPS: the whole composited image (a CNN's receptive field cannot be masked meaningfully; background pixels
  agree wherever both alphas are 0, so they add ~nothing, while silhouette errors still count).

``plain`` (no scaling, whole image): PSNR over all pixels, SSIM as scikit-image's mean SSIM over the image,
LPIPS on the whole image.

Definitions
-----------
- PSNR = 10 log10(1 / MSE) in dB (data range 1). MSE = 0 would give +inf; :func:`psnr` floors the MSE at
  ``10**(-cap_db/10)`` i.e. caps PSNR at ``cap_db`` = 100 dB by default so that means over images stay finite
  (``cap_db=None`` returns inf).
- SSIM: ``skimage.metrics.structural_similarity`` with the settings of Wang et al. 2004: Gaussian weighting
  (sigma 1.5, i.e. an 11x11 window), ``use_sample_covariance=False``, ``data_range=1.0``, ``channel_axis=-1``
  (SSIM per RGB channel, then averaged over channels). Images must be at least 11 px on each side.
  ``plain``: skimage's own mean (which drops a 5 px border); ``aligned``: the full SSIM map (``full=True``)
  averaged over channels and then over the foreground pixels.
- LPIPS: :class:`frng.perceptual.LPIPS` ``("alex")``, v0.1 linear heads, inputs mapped [0, 1] -> [-1, 1];
  reproduces the published values of ../shared/testdata/lpips_calibration to ~5e-5 (tests/test_lpips.py).
  Images must be at least 32 px on each side.

Tables report the mean of the per-image values (PSNR averaged in dB, as papers do) per group; per-image rows
are kept in CSV (:func:`write_csv`) so that any table can be recomputed (:func:`aggregate`).
"""

from __future__ import annotations

import math
import os
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from frng.io import atomic_path, composite, read_rgba, srgb_encode
from frng.plan.sections import key, register

PROTOCOLS = ("aligned", "plain")
DEFAULT_PROTOCOL = "aligned"
DEFAULT_BACKGROUND = (1.0, 1.0, 1.0)
METRICS = ("psnr", "ssim", "lpips")
RIM_PX = 2  # psnr_interior: the foreground eroded by this many pixels (scipy.ndimage.binary_erosion, 4-connected)
HIGHER_IS_BETTER = {"psnr": True, "ssim": True, "lpips": False}


@register("eval")
@dataclass(frozen=True)
class EvalConfig:
    """The config's ``eval`` section: the protocol and background of the relighting metrics (each key declared on its field)."""

    CONFIG_DOC = "relighting metrics (frng/apps/scoring.py, frng/metrics.py)"

    protocol: str = key(
        "aligned",
        "`aligned`: each RGB channel of a prediction scaled to the ground truth (least squares over the foreground), "
        "PSNR/SSIM over the foreground (RelitLRM, Neural Gaffer, TensoIR); `plain`: no scaling, whole image. Every "
        "table caption names it",
        type="string",
        enum=["aligned", "plain"],
    )
    background: tuple[float, ...] = key(
        [1.0, 1.0, 1.0],
        "linear colour both images are composited on before sRGB encoding (LPIPS always sees the whole composited "
        "image)",
        type="array",
        items={"type": "number", "minimum": 0},
        minItems=3,
        maxItems=3,
    )


# skimage structural_similarity settings (Wang et al. 2004 Gaussian SSIM).
SSIM_KWARGS = dict(gaussian_weights=True, sigma=1.5, use_sample_covariance=False, data_range=1.0, channel_axis=-1)
SSIM_WINDOW = 11  # what sigma=1.5 with skimage's truncate=3.5 gives: 2 * int(3.5 * 1.5 + 0.5) + 1


# -- preparation ------------------------------------------------------------------------------------


def _as_rgba(img: np.ndarray, name: str) -> np.ndarray:
    img = np.asarray(img, dtype=np.float32)
    if img.ndim != 3 or img.shape[-1] not in (3, 4):
        raise ValueError(f"{name}: expected an (H, W, 3|4) image, got shape {img.shape}")
    if img.shape[-1] == 3:
        img = np.concatenate([img, np.ones_like(img[..., :1])], axis=-1)
    if not np.all(np.isfinite(img)):
        raise ValueError(f"{name}: contains NaN or inf")
    return img


def foreground_mask(gt_rgba: np.ndarray, threshold: float = 0.5) -> np.ndarray:
    """(H, W, 4) ground truth -> (H, W) bool foreground mask ``alpha > threshold`` (all True for RGB input)."""
    return _as_rgba(gt_rgba, "gt")[..., 3] > threshold


def channel_scales(pred_rgb: np.ndarray, gt_rgb: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """Per-channel least-squares scale s (3,) minimising ``sum_mask (s_c * p_c - g_c)^2`` for each channel c.

    pred_rgb, gt_rgb: (H, W, 3) linear (premultiplied) RGB; mask: (H, W) bool. ``s_c = 1`` where the prediction is
    zero over the mask (nothing to scale).
    """
    p = pred_rgb[mask].astype(np.float64)  # (M, 3)
    g = gt_rgb[mask].astype(np.float64)
    num = (p * g).sum(axis=0)
    den = (p * p).sum(axis=0)
    return np.where(den > 0, num / np.where(den > 0, den, 1.0), 1.0).astype(np.float64)


def channel_brightness(pred_rgb: np.ndarray, gt_rgb: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """Per-channel ratio of means b (3,) = sum_mask g_c / sum_mask p_c of (H, W, 3) linear images over an (H, W)
    mask: how much brighter the ground truth is than the prediction, blind to where the detail sits (unlike
    :func:`channel_scales`). 1 where the prediction sums to <= 0 over the mask."""
    assert pred_rgb.shape == gt_rgb.shape and pred_rgb.shape[-1] == 3, (pred_rgb.shape, gt_rgb.shape)
    assert mask.shape == pred_rgb.shape[:2], (mask.shape, pred_rgb.shape)
    p = pred_rgb[mask].astype(np.float64).sum(axis=0)
    g = gt_rgb[mask].astype(np.float64).sum(axis=0)
    return np.where(p > 0, g / np.where(p > 0, p, 1.0), 1.0)


def prepare(
    pred: np.ndarray,
    gt: np.ndarray,
    mask: np.ndarray | None = None,
    protocol: str = DEFAULT_PROTOCOL,
    background: Sequence[float] = DEFAULT_BACKGROUND,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Apply the protocol: (pred, gt linear RGBA) -> (pred_srgb, gt_srgb, mask, scales).

    Returns pred_srgb, gt_srgb: (H, W, 3) float32 sRGB-encoded in [0, 1], composited on ``background``;
    mask: (H, W) bool (the given one, or gt alpha > 0.5); scales: (3,) the per-channel scale applied to the
    prediction (ones for ``plain``).
    """
    if protocol not in PROTOCOLS:
        raise ValueError(f"protocol must be one of {PROTOCOLS}, got {protocol!r}")
    pred = _as_rgba(pred, "pred")
    gt = _as_rgba(gt, "gt")
    if pred.shape != gt.shape:
        raise ValueError(f"pred and gt shapes differ: {pred.shape} vs {gt.shape}")
    mask = foreground_mask(gt) if mask is None else np.asarray(mask, dtype=bool)
    if mask.shape != gt.shape[:2]:
        raise ValueError(f"mask shape {mask.shape} does not match the image {gt.shape[:2]}")
    scales = np.ones(3)
    if protocol == "aligned":
        if not mask.any():
            raise ValueError("aligned protocol: the foreground mask is empty (nothing to align or evaluate)")
        scales = channel_scales(pred[..., :3], gt[..., :3], mask)
        pred = pred.copy()
        pred[..., :3] *= scales.astype(np.float32)
    pred_srgb = srgb_encode(composite(pred, background))
    gt_srgb = srgb_encode(composite(gt, background))
    return pred_srgb, gt_srgb, mask, scales


# -- metrics on encoded images --------------------------------------------------------------------------


def psnr(pred: np.ndarray, gt: np.ndarray, mask: np.ndarray | None = None, cap_db: float | None = 100.0) -> float:
    """PSNR in dB of (H, W, C) images in [0, 1] (data range 1), over the mask's pixels (H, W) bool or all pixels.

    MSE = 0 gives ``cap_db`` (default 100), or +inf with ``cap_db=None``.
    """
    diff = np.asarray(pred, np.float64) - np.asarray(gt, np.float64)
    if mask is not None:
        if not np.any(mask):
            raise ValueError("psnr: empty mask")
        diff = diff[np.asarray(mask, bool)]
    mse = float(np.mean(diff * diff))
    if cap_db is not None:
        mse = max(mse, 10.0 ** (-cap_db / 10.0))
    if mse == 0.0:
        return math.inf
    return float(-10.0 * math.log10(mse))


def interior(mask: np.ndarray, rim_px: int = RIM_PX) -> np.ndarray:
    """(H, W) bool foreground -> the same without its outer ``rim_px`` pixels (4-connected erosion; pixels on the
    image border count as inside). Empty when the foreground is thinner than the rim."""
    from scipy.ndimage import binary_erosion

    mask = np.asarray(mask, bool)
    return binary_erosion(mask, iterations=rim_px, border_value=1) if rim_px > 0 else mask


def silhouette_iou(pred: np.ndarray, mask: np.ndarray) -> float:
    """Intersection over union of the prediction's silhouette (alpha > 0.5; (H, W, 4) linear premultiplied RGBA, or
    (H, W, 3) read as opaque) and the foreground ``mask`` (H, W) bool; 1.0 when both are empty."""
    sil = _as_rgba(pred, "pred")[..., 3] > 0.5
    mask = np.asarray(mask, bool)
    union = int(np.count_nonzero(sil | mask))
    return float(np.count_nonzero(sil & mask) / union) if union else 1.0


def ssim(pred: np.ndarray, gt: np.ndarray, mask: np.ndarray | None = None) -> float:
    """SSIM of (H, W, 3) images in [0, 1] (settings in :data:`SSIM_KWARGS`).

    mask None: scikit-image's mean SSIM. mask (H, W) bool: the SSIM map averaged over channels, then over the
    mask's pixels.
    """
    from skimage.metrics import structural_similarity

    pred = np.asarray(pred, np.float64)
    gt = np.asarray(gt, np.float64)
    if min(pred.shape[:2]) < SSIM_WINDOW:
        raise ValueError(f"ssim: images must be at least {SSIM_WINDOW} px on each side, got {pred.shape[:2]}")
    if mask is None:
        return float(structural_similarity(pred, gt, **SSIM_KWARGS))
    if not np.any(mask):
        raise ValueError("ssim: empty mask")
    _, smap = structural_similarity(pred, gt, full=True, **SSIM_KWARGS)  # smap (H, W, 3)
    return float(smap.mean(axis=-1)[np.asarray(mask, bool)].mean())


def lpips(pred: np.ndarray, gt: np.ndarray, net: str = "alex", device: str = "cpu") -> float:
    """LPIPS v0.1 of (H, W, 3) images in [0, 1] (H, W >= 32), whole image; lower is better."""
    import torch

    from frng.perceptual import lpips_model

    model = lpips_model(net, device)
    x = torch.from_numpy(np.ascontiguousarray(pred, dtype=np.float32)).permute(2, 0, 1)[None].to(device)
    y = torch.from_numpy(np.ascontiguousarray(gt, dtype=np.float32)).permute(2, 0, 1)[None].to(device)
    with torch.no_grad():
        return float(model(x, y, normalize=True)[0])


# -- one pair ---------------------------------------------------------------------------------------


def evaluate_pair(
    pred: np.ndarray,
    gt: np.ndarray,
    mask: np.ndarray | None = None,
    protocol: str = DEFAULT_PROTOCOL,
    background: Sequence[float] = DEFAULT_BACKGROUND,
    lpips_net: str = "alex",
    device: str = "cpu",
) -> dict:
    """All metrics of one prediction against its ground truth, under ``protocol`` (see the module docstring).

    pred, gt: (H, W, 4) linear premultiplied RGBA (or (H, W, 3)), float; mask: (H, W) bool or None (gt alpha >
    0.5). Returns ``{"psnr", "psnr_aligned", "psnr_plain", "psnr_interior", "silhouette_iou", "ssim", "lpips",
    "protocol", "scale_r", "scale_g", "scale_b", "brightness_r", "brightness_g", "brightness_b", "fg_fraction"}``
    (``psnr_aligned`` / ``psnr_plain``: the PSNR under each protocol, one of them ``psnr``: what the claims table's
    second protocol reads without a second scoring pass; ``psnr_interior``: PSNR over
    :func:`interior` of the mask, both protocols; NaN when the foreground has no interior; ``silhouette_iou``:
    :func:`silhouette_iou` of the prediction against the mask).
    """
    p, g, mask, scales = prepare(pred, gt, mask, protocol, background)
    bright = channel_brightness(_as_rgba(pred, "pred")[..., :3], _as_rgba(gt, "gt")[..., :3], mask)
    region = mask if protocol == "aligned" else None
    inner = interior(mask)
    by_protocol = {protocol: psnr(p, g, region)}
    for other in PROTOCOLS:
        if other != protocol:
            po, go, _, _ = prepare(pred, gt, mask, other, background)
            by_protocol[other] = psnr(po, go, mask if other == "aligned" else None)
    return {
        "psnr": by_protocol[protocol],
        **{f"psnr_{k}": by_protocol[k] for k in PROTOCOLS},
        "psnr_interior": psnr(p, g, inner) if inner.any() else math.nan,
        "silhouette_iou": silhouette_iou(pred, mask),
        "ssim": ssim(p, g, region),
        "lpips": lpips(p, g, lpips_net, device),
        "protocol": protocol,
        "scale_r": float(scales[0]),
        "scale_g": float(scales[1]),
        "scale_b": float(scales[2]),
        "brightness_r": float(bright[0]),
        "brightness_g": float(bright[1]),
        "brightness_b": float(bright[2]),
        "fg_fraction": float(mask.mean()),
    }


def psnr_pair(
    pred: np.ndarray,
    gt: np.ndarray,
    mask: np.ndarray | None = None,
    protocol: str = DEFAULT_PROTOCOL,
    background: Sequence[float] = DEFAULT_BACKGROUND,
) -> float:
    """The PSNR of :func:`evaluate_pair` alone (same protocol, mask and background), without SSIM and LPIPS."""
    p, g, mask, _ = prepare(pred, gt, mask, protocol, background)
    return psnr(p, g, mask if protocol == "aligned" else None)


def evaluate_files(pred_path: str | os.PathLike, gt_path: str | os.PathLike, **kwargs) -> dict:
    """:func:`evaluate_pair` on two RGBA EXR files (both must have alpha); errors name the file
    (``frng.io.ImageError``)."""
    # the ground truth's alpha is the foreground mask and the prediction's its silhouette: RGB-only files are
    # refused rather than read as fully opaque
    pred, gt = read_rgba(pred_path, require_alpha=True), read_rgba(gt_path, require_alpha=True)
    if pred.shape != gt.shape:
        raise ValueError(f"{pred_path}: shape {pred.shape} differs from the ground truth {gt_path} {gt.shape}")
    return evaluate_pair(pred, gt, **kwargs)


# -- per-image rows, CSV, aggregation ------------------------------------------------------------------


def to_frame(rows: Iterable[Mapping]):
    """Per-image rows (dicts: identifying columns such as dataset/variant/method/object/light/view, plus the
    output of :func:`evaluate_pair`) -> pandas DataFrame, one row per image."""
    import pandas as pd

    return pd.DataFrame(list(rows))


def write_csv(df, path: str | os.PathLike) -> Path:
    """Write a DataFrame as CSV atomically (no index, floats at full precision). Returns the path."""
    path = Path(path)
    with atomic_path(path) as tmp:
        df.to_csv(tmp, index=False)
    return path


def read_csv(path: str | os.PathLike):
    import pandas as pd

    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"{path} does not exist")
    return pd.read_csv(path)


def _median_abs_log2(df, prefix: str) -> float:
    cols = [f"{prefix}_{c}" for c in "rgb"]
    if not set(cols) <= set(df.columns) or not len(df):
        return float("nan")
    return float(np.median(np.abs(np.log2(np.clip(df[cols].to_numpy(dtype=float), 1e-6, None)))))


def scale_log2(df) -> float:
    """How much colour repair the aligned protocol did: the median over rows (images) and channels of
    ``|log2 scale_c|`` (0 = none; 0.25 = a 19% correction). NaN without scale columns (plain protocol rows carry
    scale 1: 0)."""
    return _median_abs_log2(df, "scale")


def brightness_log2(df) -> float:
    """How far off the predictions' brightness is, by the ratio of means (:func:`channel_brightness`): the median
    over rows and channels of ``|log2 brightness_c|``. NaN without brightness columns."""
    return _median_abs_log2(df, "brightness")


def aggregate(df, by: Sequence[str], metrics: Sequence[str] = METRICS):
    """Mean of each metric per group of ``by`` columns (group order as first seen), plus ``n`` (image count).

    A ``protocol`` column, when present, must either be one of ``by`` or hold a single value: means over mixed
    protocols are refused. Infinite PSNRs (``cap_db=None``) make a group's mean inf, deliberately visible.
    """
    by = list(by)
    missing = [c for c in by + list(metrics) if c not in df.columns]
    if missing:
        raise KeyError(f"aggregate: columns {missing} not in {list(df.columns)}")
    if "protocol" in df.columns and "protocol" not in by and df["protocol"].nunique() > 1:
        raise ValueError(f"aggregate: rows mix protocols {sorted(df['protocol'].unique())}; add 'protocol' to by")
    g = df.groupby(by, sort=False, dropna=False)
    out = g[list(metrics)].mean()
    out.insert(0, "n", g.size())
    out = out.reset_index()
    if "protocol" in df.columns and "protocol" not in by:
        out["protocol"] = df["protocol"].iloc[0] if len(df) else None
    return out


def other_light(lights: list[str], light: str) -> str:
    """The light an image rendered for ``light`` is scored against in the light-sensitivity check: the next one in
    the object's list of test lights (cyclic); ``light`` itself when it is the only one."""
    return lights[(lights.index(light) + 1) % len(lights)]
