"""The published metric protocols of the relighting benchmarks, one function each (``PROTOCOLS`` maps the name
recorded in an imported object's ``meta.json`` ``benchmark.protocol`` to it). Every table that uses one names it.

All functions take the prediction and the ground truth as stored in this project (linear, premultiplied RGBA,
(H, W, 4) float) plus what the protocol needs, and return a dict of metrics; ``psnr`` is always the headline
number of the benchmark (Stanford-ORB: PSNR-H).

``tensoir`` -- TensoIR (github.com/Haian-Jin/TensoIR, ``renderer.py`` / ``scripts/relight_importance.py``):
    both images composited on WHITE, clipped, sRGB-encoded; PSNR / SSIM / LPIPS over the WHOLE image, no mask and
    no image-space colour scaling (:func:`frng.metrics.evaluate_pair` with the ``plain`` protocol and a white
    background). TensoIR's own rescaling (per-channel median of gt albedo / predicted albedo over the mask, applied
    to the albedo before shading, after NeRFactor) is a step of the method, not of the image metric: a method
    without an explicit albedo, like F-RNG, is scored on its images as they are.
``nerf-synthetic`` -- the NeRF protocol, the same computation as ``tensoir``.
``orb`` -- Stanford-ORB (github.com/StanfordORB/Stanford-ORB, ``orb/utils/test.py`` ``compute_similarity`` and
    ``orb/utils/metrics.py`` ``calc_PSNR``), relighting: ``scale_invariant=True``, ``divide_mask=False``:

    - the gt mask (float -> uint8 x 255) eroded with a 5 x 5 box (``cv2.erode``; border = no erosion), > 127;
    - both images multiplied by the eroded mask, gt negatives set to 0;
    - PSNR-H: ``use_gt_median``: both images multiplied by ``srgb(clip(gt, 0, 1)).mean() / clip(gt, 0, 1).mean()``
      (when that mean > 1e-8); PSNR-L: no median, sRGB tone mapping after clipping;
    - per-channel least-squares scale ``(gt * pred).sum(0) / (pred ** 2).sum(0)`` over the eroded mask's pixels
      (a channel whose prediction has ``sum(p^2) <= 1e-6`` there gets ones instead);
    - clip both to [0, max_value] (4 for PSNR-H, 1 for PSNR-L), tone map for PSNR-L (ORB's ``rgb_to_srgb``);
    - MSE over the WHOLE image (``.mean()``: background pixels are 0 in both), PSNR ``-10 log10(mse)``, floored by
      the PSNR of a constant 0.5 x mask image (``max(out, lb)``).

    ORB's SSIM (kornia, 3 x 3 window) and LPIPS-VGG are not reproduced here (``ssim``/``lpips`` are NaN).
``owl`` -- Objects With Lighting (github.com/isl-org/objects-with-lighting, ``scripts/evaluate.py``
    ``scale_and_tonemap_prediction_image`` and ``utils/metrics.py``), for linear (EXR) predictions:

    - the ground truth is the published 8-bit tone-mapped image ``(x 2^e)^(1/2.2)`` (re-made here from the
      imported linear target with its exposure ``e``, i.e. ``gt_exposure_xxxx.txt``), in [0, 1];
    - mask: gt mask > 0.9 and NOT over-exposed (``max over channels of gt < 1``);
    - the best exposure ``x`` by ``scipy.optimize.minimize_scalar(fn, (-10, max_exposure))`` of the mean L1 between
      ``clip((pred 2^x)^(1/2.2), 0, 1)`` and gt over the mask, ``max_exposure = log2(0.95^2.2 / smallest positive
      prediction value)``; then a per-channel colour balance ``scipy.optimize.minimize(fn, ones, bounds=3 x [(0.5,
      2)])`` of the same L1; the prediction tone-mapped with both;
    - PSNR (``skimage`` ``peak_signal_noise_ratio`` of the masked pixels, data range 1), SSIM (``skimage``
      ``structural_similarity`` of the masked images, its defaults (7 x 7 uniform window), ``channel_axis=-1``,
      ``data_range=1``, map averaged over the mask), LPIPS-alex of the masked images (``mask * (x * 2 - 1)``): here
      the whole-image LPIPS of :mod:`frng.perceptual` instead of the mask-average of its spatial map.
"""

from __future__ import annotations

import math

import numpy as np

OWL_GAMMA = 2.2  # utils/constants.py DEFAULT_GAMMA


def _rgba(x: np.ndarray) -> np.ndarray:
    x = np.asarray(x, dtype=np.float32)
    if x.ndim != 3 or x.shape[-1] not in (3, 4):
        raise ValueError(f"expected an (H, W, 3|4) image, got {x.shape}")
    if x.shape[-1] == 3:
        x = np.concatenate([x, np.ones_like(x[..., :1])], -1)
    return x


# -- TensoIR / NeRF-synthetic ----------------------------------------------------------------------------------


def tensoir(pred: np.ndarray, gt: np.ndarray, lpips: bool = True, **_) -> dict:
    """White background, whole image, no scaling (see the module docstring)."""
    from frng import metrics as M

    p, g, _, _ = M.prepare(_rgba(pred), _rgba(gt), protocol="plain", background=(1.0, 1.0, 1.0))
    return {
        "psnr": M.psnr(p, g, cap_db=None),
        "ssim": M.ssim(p, g) if min(p.shape[:2]) >= 11 else math.nan,
        "lpips": M.lpips(p, g) if lpips and min(p.shape[:2]) >= 32 else math.nan,
        "protocol": "tensoir",
    }


def nerf_synthetic(pred: np.ndarray, gt: np.ndarray, lpips: bool = True, **_) -> dict:
    return tensoir(pred, gt, lpips) | {"protocol": "nerf-synthetic"}


# -- Stanford-ORB --------------------------------------------------------------------------------------------


def orb_srgb(x: np.ndarray) -> np.ndarray:
    """ORB's ``rgb_to_srgb`` (orb/utils/preprocess.py): the sRGB curve, 12.92 x below 0.0031308."""
    x = np.asarray(x, dtype=np.float64)
    return np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(np.maximum(x, 0.0031308), 1 / 2.4) - 0.055)


def orb_erode(mask: np.ndarray) -> np.ndarray:
    """``cv2.erode(uint8(mask * 255), ones((5, 5)))`` > 127 (OpenCV's default border never erodes)."""
    from scipy.ndimage import minimum_filter

    m8 = np.clip(np.asarray(mask, dtype=np.float32) * 255, 0, 255).astype(np.uint8)
    return (minimum_filter(m8, size=5, mode="constant", cval=255) > 127).astype(np.float32)


def orb_psnr(
    pred_rgb: np.ndarray,
    gt_rgb: np.ndarray,
    mask: np.ndarray,
    max_value: float,
    use_gt_median: bool,
    tonemapping: bool,
    scale_invariant: bool = True,
) -> float:
    """``calc_PSNR(..., divide_mask=False)`` of Stanford-ORB for linear RGB images and a [0, 1] mask."""
    m = orb_erode(mask)
    p = np.asarray(pred_rgb, dtype=np.float64) * m[..., None]
    g = np.asarray(gt_rgb, dtype=np.float64) * m[..., None]
    g[g < 0] = 0
    if use_gt_median and np.clip(g, 0, 1).mean() > 1e-8:
        med = orb_srgb(np.clip(g, 0, 1)).mean() / np.clip(g, 0, 1).mean()
        p, g = p * med, g * med
    if scale_invariant:
        sel = m > 0.5
        pp, gp = p[sel].copy(), g[sel]
        for c in range(3):
            if (pp[:, c] ** 2).sum() <= 1e-6:
                pp[:, c] = 1.0
        scale = (gp * pp).sum(0) / (pp**2).sum(0)
        p = scale * p
    p, g = np.clip(p, 0, max_value), np.clip(g, 0, max_value)
    if tonemapping:
        p, g = orb_srgb(p), orb_srgb(g)
    mse = ((p - g) ** 2).mean()
    lb = ((0.5 * m[..., None] - g) ** 2).mean()
    out = -10.0 / math.log(10.0) * math.log(mse) if mse > 0 else math.inf
    return max(out, -10.0 / math.log(10.0) * math.log(lb) if lb > 0 else math.inf)


def orb(pred: np.ndarray, gt: np.ndarray, mask: np.ndarray | None = None, **_) -> dict:
    """Stanford-ORB relighting: PSNR-H (headline ``psnr``) and PSNR-L. ``mask``: the gt mask (default gt alpha)."""
    pred, gt = _rgba(pred), _rgba(gt)
    mask = gt[..., 3] if mask is None else mask
    h = orb_psnr(pred[..., :3], gt[..., :3], mask, 4.0, True, False)
    l = orb_psnr(pred[..., :3], gt[..., :3], mask, 1.0, False, True)
    return {"psnr": h, "psnr_h": h, "psnr_l": l, "ssim": math.nan, "lpips": math.nan, "protocol": "orb"}


# -- OWL -----------------------------------------------------------------------------------------------------


def owl_tonemap(linear: np.ndarray, exposure: float, gamma: float = OWL_GAMMA) -> np.ndarray:
    """``apply_exposure_and_gamma`` (utils/hdri.py): ``clip(x 2^e, 0, inf)^(1/gamma)`` (unclipped above)."""
    return np.power(np.clip(np.asarray(linear, dtype=np.float64) * 2.0**exposure, 0, None), 1.0 / gamma)


def owl_fit(
    pred_linear: np.ndarray, gt: np.ndarray, mask: np.ndarray, balance_colors: bool = True, autoexposure: bool = True
) -> tuple[np.ndarray, float, np.ndarray]:
    """``scale_and_tonemap_prediction_image`` of OWL: (tone-mapped prediction in [0, 1], exposure, balance)."""
    from scipy.optimize import minimize, minimize_scalar

    gamma = OWL_GAMMA
    pr = np.asarray(pred_linear, dtype=np.float32)
    gt = np.asarray(gt, dtype=np.float32)
    m = (gt.max(axis=-1, keepdims=True) < 1).astype(np.float32) * np.asarray(mask, np.float32).reshape(
        gt.shape[:2] + (1,)
    )
    sel = m[..., 0] > 0.9

    def fn_e(x):
        return np.abs(np.clip(owl_tonemap(pr[sel], x, gamma), 0, 1) - gt[sel]).mean()

    exposure = 0.0
    if autoexposure:
        smallest = pr[sel].min(axis=-1)
        smallest = smallest[smallest > 0].min()
        max_exposure = np.log2(0.95**gamma / smallest)
        exposure = float(minimize_scalar(fn_e, (-10, max_exposure)).x)
    balance = np.ones(3, dtype=np.float32)
    if balance_colors:

        def fn_c(x):
            tmp = pr[sel].reshape(-1, 3) * x[None, :]
            return np.abs(np.clip(owl_tonemap(tmp, exposure, gamma), 0, 1) - gt[sel]).mean()

        balance = minimize(fn_c, np.ones((3,), dtype=np.float32), bounds=3 * [(0.5, 2.0)]).x.astype(np.float32)
        pr = pr * balance[None, None, :]
    return np.clip(owl_tonemap(pr, exposure, gamma), 0, 1).astype(np.float32), exposure, balance


def owl(
    pred: np.ndarray, gt: np.ndarray, exposure: float = 0.0, mask: np.ndarray | None = None, lpips: bool = True, **_
) -> dict:
    """OWL's evaluation of a linear prediction against the tone-mapped ground truth (gt exposure ``exposure``)."""
    from skimage.metrics import peak_signal_noise_ratio, structural_similarity

    pred, gt = _rgba(pred), _rgba(gt)
    mask = (gt[..., 3] if mask is None else np.asarray(mask, np.float32))[..., None]
    gt_tm = np.clip(owl_tonemap(gt[..., :3], exposure), 0, 1).astype(np.float32)
    p, e, bal = owl_fit(pred[..., :3], gt_tm, mask)
    sel = mask[..., 0] > 0.5
    psnr = float(peak_signal_noise_ratio(gt_tm[sel].ravel(), p[sel].ravel(), data_range=1.0))
    ssim = math.nan
    if min(p.shape[:2]) >= 7:
        _, S = structural_similarity(p * mask, gt_tm * mask, channel_axis=-1, full=True, data_range=1.0)
        ssim = float(S[sel].mean())
    lp = math.nan
    if lpips and min(p.shape[:2]) >= 32:
        from frng import metrics as M

        # OWL feeds mask * (x * 2 - 1) to LPIPS: a [0, 1] image that is 0.5 outside the mask
        lp = M.lpips(p * mask + 0.5 * (1 - mask), gt_tm * mask + 0.5 * (1 - mask))
    return {
        "psnr": psnr,
        "ssim": ssim,
        "lpips": lp,
        "protocol": "owl",
        "exposure_fit": e,
        "balance_r": float(bal[0]),
        "balance_g": float(bal[1]),
        "balance_b": float(bal[2]),
    }


PROTOCOLS = {"tensoir": tensoir, "nerf-synthetic": nerf_synthetic, "orb": orb, "owl": owl}


def score(protocol: str, pred: np.ndarray, gt: np.ndarray, **kw) -> dict:
    if protocol not in PROTOCOLS:
        raise ValueError(f"unknown benchmark protocol {protocol!r} ({', '.join(PROTOCOLS)})")
    return PROTOCOLS[protocol](pred, gt, **kw)
