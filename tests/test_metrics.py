"""frng.metrics: PSNR/SSIM/LPIPS definitions, the aligned and plain protocols, masking, aggregation."""

import math

import numpy as np
import pandas as pd
import pytest
from skimage.metrics import structural_similarity

from frng import metrics as M
from frng.io import composite, srgb_encode


def _scene(size=48, seed=0):
    """A linear premultiplied RGBA ground truth: textured disc on a transparent background."""
    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[:size, :size]
    alpha = (((yy - size / 2) ** 2 + (xx - size / 2) ** 2) < (size / 3) ** 2).astype(np.float32)
    rgb = (0.2 + 0.6 * rng.random((size, size, 3))).astype(np.float32) * alpha[..., None]
    return np.concatenate([rgb, alpha[..., None]], axis=-1)


def test_psnr_known_mse():
    a = np.zeros((16, 16, 3))
    b = np.full((16, 16, 3), 0.1)  # MSE 0.01 -> 20 dB
    assert M.psnr(a, b) == pytest.approx(20.0, abs=1e-9)
    mask = np.zeros((16, 16), bool)
    mask[:4] = True
    b2 = b.copy()
    b2[~mask] = 0.9  # outside the mask: ignored
    assert M.psnr(a, b2, mask) == pytest.approx(20.0, abs=1e-9)


def test_psnr_identical():
    a = np.random.default_rng(0).random((8, 8, 3))
    assert M.psnr(a, a) == 100.0
    assert math.isinf(M.psnr(a, a, cap_db=None))


def test_aligned_recovers_global_scale_plain_does_not():
    gt = _scene()
    pred = gt.copy()
    pred[..., :3] *= np.array([0.5, 0.7, 1.3], np.float32)  # a per-channel colour scale (light ambiguity)
    aligned = M.evaluate_pair(pred, gt, protocol="aligned")
    plain = M.evaluate_pair(pred, gt, protocol="plain")
    assert aligned["psnr"] > 60 and aligned["ssim"] > 0.999 and aligned["lpips"] < 1e-3
    assert [aligned[f"scale_{c}"] for c in "rgb"] == pytest.approx([2.0, 1 / 0.7, 1 / 1.3], rel=1e-5)
    assert plain["psnr"] < 25 and plain["lpips"] > 0.01
    assert plain["scale_r"] == 1.0
    assert M.evaluate_pair(gt, gt)["psnr"] == 100.0
    # every row carries both protocols' PSNR (the claims table's second protocol): the same numbers either way
    for r in (aligned, plain):
        assert r["psnr_aligned"] == aligned["psnr"] and r["psnr_plain"] == plain["psnr"]


def test_brightness_is_the_ratio_of_means_and_ignores_where_detail_sits():
    gt = _scene()
    fg = gt[..., 3] > 0.5
    # a global colour scale: both estimators recover it
    pred = gt.copy()
    pred[..., :3] *= np.array([0.5, 0.7, 1.3], np.float32)
    m = M.evaluate_pair(pred, gt)
    assert [m[f"brightness_{c}"] for c in "rgb"] == pytest.approx([2.0, 1 / 0.7, 1 / 1.3], rel=1e-5)
    # the right mean, detail in the wrong places (the foreground's colours shuffled): the ratio of means stays 1,
    # the least-squares scale shrinks below 1 and would read the prediction as too bright
    rng = np.random.default_rng(0)
    pred = gt.copy()
    idx = np.flatnonzero(fg.ravel())
    flat = pred.reshape(-1, 4)
    flat[idx, :3] = flat[rng.permutation(idx), :3]
    m = M.evaluate_pair(pred, gt)
    assert [m[f"brightness_{c}"] for c in "rgb"] == pytest.approx([1.0, 1.0, 1.0], rel=1e-5)
    assert max(m[f"scale_{c}"] for c in "rgb") < 0.99
    # an all-black prediction has nothing to measure
    assert M.evaluate_pair(np.zeros_like(gt), gt)["brightness_r"] == 1.0
    df = pd.DataFrame({"brightness_r": [2.0, 0.5], "brightness_g": [1.0, 1.0], "brightness_b": [4.0, 1.0]})
    assert M.brightness_log2(df) == 0.5


def test_aligned_masking_ignores_background():
    gt = _scene()
    pred = gt.copy()
    fg = gt[..., 3] > 0.5
    # An opaque green floater everywhere outside the object: only the background is wrong.
    pred[~fg] = np.array([0.0, 0.5, 0.0, 1.0], np.float32)
    aligned = M.evaluate_pair(pred, gt, protocol="aligned")
    plain = M.evaluate_pair(pred, gt, protocol="plain")
    assert aligned["psnr"] == 100.0  # PSNR sees foreground pixels only
    # SSIM is averaged over foreground pixels, but windows near the silhouette still overlap the background
    assert aligned["ssim"] > plain["ssim"] + 0.1
    assert plain["psnr"] < 15
    # an explicit mask is honoured
    mask = np.zeros_like(fg)
    mask[:5, :5] = True
    assert M.evaluate_pair(pred, gt, mask=mask, protocol="aligned")["psnr"] < 15
    with pytest.raises(ValueError, match="empty"):
        M.evaluate_pair(pred, gt, mask=np.zeros_like(fg), protocol="aligned")


def _skimage_ssim(p, g, **kw):
    """scikit-image's SSIM with the Wang et al. settings the metric claims (Gaussian 11x11, sigma 1.5, population
    covariance), in float64."""
    return structural_similarity(
        p.astype(np.float64),
        g.astype(np.float64),
        data_range=1.0,
        channel_axis=-1,
        gaussian_weights=True,
        sigma=1.5,
        use_sample_covariance=False,
        **kw,
    )


def test_ssim_matches_skimage_and_encoding():
    gt = _scene(seed=1)
    pred = np.clip(gt + np.random.default_rng(2).normal(0, 0.05, gt.shape).astype(np.float32), 0, 1)
    pred[..., 3] = gt[..., 3]
    p = srgb_encode(composite(pred, (1, 1, 1)))
    g = srgb_encode(composite(gt, (1, 1, 1)))
    ref = _skimage_ssim(p, g)
    out = M.evaluate_pair(pred, gt, protocol="plain")
    assert out["ssim"] == pytest.approx(ref, abs=1e-9)
    assert out["psnr"] == pytest.approx(-10 * np.log10(np.mean((p.astype(np.float64) - g) ** 2)), abs=1e-6)
    p2, g2, mask, _ = M.prepare(pred, gt, protocol="aligned")
    _, smap = _skimage_ssim(p2, g2, full=True)
    assert M.evaluate_pair(pred, gt)["ssim"] == pytest.approx(smap.mean(-1)[mask].mean(), abs=1e-9)


def test_bad_inputs():
    gt = _scene()
    with pytest.raises(ValueError, match="shapes differ"):
        M.evaluate_pair(gt[:40], gt)
    with pytest.raises(ValueError, match="protocol"):
        M.evaluate_pair(gt, gt, protocol="scaled")
    bad = gt.copy()
    bad[0, 0, 0] = np.nan
    with pytest.raises(ValueError, match="NaN"):
        M.evaluate_pair(bad, gt)


def test_rows_csv_aggregate(tmp_path):
    gt = _scene()
    rows = []
    for variant, noise in (("full", 0.01), ("no_priors", 0.1)):
        for view in range(2):
            rng = np.random.default_rng(view)
            pred = gt.copy()
            pred[..., :3] = np.clip(pred[..., :3] + rng.normal(0, noise, gt[..., :3].shape), 0, None) * gt[..., 3:]
            rows.append({"dataset": "synthetic", "variant": variant, "view": view, **M.evaluate_pair(pred, gt)})
    df = M.to_frame(rows)
    path = M.write_csv(df, tmp_path / "metrics" / "per_image.csv")
    back = M.read_csv(path)
    assert len(back) == 4 and set(M.METRICS) <= set(back.columns)
    agg = M.aggregate(back, ["dataset", "variant"])
    assert list(agg["variant"]) == ["full", "no_priors"] and list(agg["n"]) == [2, 2]
    assert agg.loc[0, "psnr"] == pytest.approx(back["psnr"][:2].mean())
    assert agg.loc[0, "psnr"] > agg.loc[1, "psnr"] and agg.loc[0, "lpips"] < agg.loc[1, "lpips"]
    assert (agg["protocol"] == "aligned").all()
    mixed = back.copy()
    mixed.loc[0, "protocol"] = "plain"
    with pytest.raises(ValueError, match="mix protocols"):
        M.aggregate(mixed, ["variant"])


def test_interior_drops_the_rim_only():
    mask = np.zeros((12, 12), bool)
    mask[1:11, 1:11] = True  # a 10 x 10 square
    inner = M.interior(mask)
    assert inner.sum() == 6 * 6 and inner[3:9, 3:9].all()
    assert M.interior(mask, rim_px=0).sum() == 100
    thin = np.zeros((12, 12), bool)
    thin[5:8, :] = True  # 3 px wide, touching the left and right image borders
    assert not M.interior(thin).any()
    wall = np.ones((6, 6), bool)  # the image border is not a silhouette
    assert M.interior(wall).all()


def test_psnr_interior_ignores_silhouette_errors():
    gt = _scene()
    pred = gt.copy()
    fg = gt[..., 3] > 0.5
    rim = fg & ~M.interior(fg)
    pred[rim, :3] = 0.0  # the outline wrong, the interior exact
    m = M.evaluate_pair(pred, gt)
    assert m["psnr"] < 25 and m["psnr_interior"] == 100.0
    strip = np.zeros((40, 40, 4), np.float32)
    strip[5:35, 10:13] = 1.0  # 3 px wide: no interior
    assert math.isnan(M.evaluate_pair(strip, strip)["psnr_interior"])


def test_silhouette_iou_counts_the_renders_outline_against_the_mask():
    gt = np.zeros((32, 32, 4), np.float32)
    gt[8:12, 8:12] = (0.3, 0.3, 0.3, 1.0)  # 16 foreground pixels
    fat = np.zeros_like(gt)
    fat[8:12, 8:14] = (0.3, 0.3, 0.3, 1.0)  # 24 pixels: the 16 plus 8 outside
    assert M.evaluate_pair(gt, gt)["silhouette_iou"] == 1.0
    assert M.evaluate_pair(fat, gt)["silhouette_iou"] == 16 / 24
    faint = fat.copy()
    faint[:, 12:, 3] = 0.4  # outside, but below the silhouette's threshold
    assert M.silhouette_iou(faint, gt[..., 3] > 0.5) == 1.0
    assert M.silhouette_iou(np.zeros_like(gt), np.zeros((32, 32), bool)) == 1.0
