"""The held-out report of `frng reconstruct --measure-heldout` (frng.apps.capture_heldout) without trained models: the
depth warp of the baseline on a textured plane, the nearest input by camera direction, and the report of a synthetic
asset scored at held-out cameras against its own renders (the smoke-tier run end to end: tests/test_reconstruct.py)."""

from __future__ import annotations

import math

import numpy as np
import torch
from test_capture import DIST, FOV, RES, synthetic_asset

from frng import camera
from frng.apps import capture_heldout
from frng.apps.capture import Capture, rig_cameras


def _plane_texture(x, y):
    return 0.5 + 0.4 * np.sin(3.0 * x) * np.cos(2.0 * y)


def _plane_view(c2w, intr, res):
    """The plane z = 0 with a smooth texture seen by an OpenCV camera: (RGBA (res, res, 4), depth (res, res))."""
    uv = camera.pixel_centers(res, res, dtype=torch.float64).numpy()
    fx, fy, cx, cy = intr
    d = np.stack([(uv[..., 0] - cx) / fx, (uv[..., 1] - cy) / fy, np.ones((res, res))], -1) @ c2w[:3, :3].T
    o = c2w[:3, 3]
    s = -o[2] / d[..., 2]  # along the ray to z = 0
    p = o + s[..., None] * d
    depth = s  # camera-frame z (the ray's z component in camera space is 1)
    v = _plane_texture(p[..., 0], p[..., 1])
    rgba = np.stack([v, 1 - v, 0.5 * v, np.ones_like(v)], -1).astype(np.float32)
    return rgba, depth


def test_warp_through_the_depth_reproduces_the_other_view():
    res = 48
    K = camera.intrinsics_from_fov(40.0, res, res)
    src = camera.look_at(np.array([0.4, -0.2, 3.0]), up=(0.0, 1.0, 0.0))
    dst = camera.look_at(np.array([-0.3, 0.3, 2.8]), up=(0.0, 1.0, 0.0))
    src_rgba, _ = _plane_view(src, K, res)
    want, depth = _plane_view(dst, K, res)
    got = capture_heldout.warp(src_rgba, src, K, depth, dst, K)
    inner = got[..., 3] > 0  # where the warped point lies inside the source (its edge pixels' outer half included)
    assert 0.7 < inner.mean() < 1.0
    err = np.abs(got[inner] - want[inner])
    assert err.max() < 0.03 and err.mean() < 0.003  # bilinear resampling of a smooth texture
    # no depth -> transparent
    none = capture_heldout.warp(src_rgba, src, K, np.full((res, res), np.nan), dst, K)
    assert not none.any()


def test_nearest_input_by_camera_direction():
    rig = np.stack([c.c2w for c in rig_cameras(6, DIST, FOV, RES)])  # azimuth 0, 90, 180, 270 @ 0; 45, 225 @ 45
    held = np.stack([camera.look_at(camera.spherical_to_cartesian(a, e, 2.0 * DIST)) for a, e in [(80, 5), (40, 50)]])
    idx, ang = capture_heldout.nearest_inputs(held, rig)

    def between(a1, e1, a2, e2):
        a1, e1, a2, e2 = np.radians([a1, e1, a2, e2])
        return math.degrees(math.acos(np.sin(e1) * np.sin(e2) + np.cos(e1) * np.cos(e2) * np.cos(a1 - a2)))

    assert idx.tolist() == [1, 4] and np.allclose(ang, [between(80, 5, 90, 0), between(40, 50, 45, 45)], atol=1e-6)


def _views(renderer, env, cams, names, seeds):
    """Renders at ``cams`` (each view with its own light-sample seed) as a :class:`Capture`."""
    c2w = np.stack([c.c2w for c in cams])
    intr = np.stack([c.intr for c in cams])
    f = lambda a: torch.tensor(a).float()[None]  # noqa: E731
    img = np.concatenate(
        [
            renderer.render(torch.from_numpy(env), f(c), f(k), RES, RES, generator=torch.Generator().manual_seed(s))
            for c, k, s in zip(c2w, intr, seeds)
        ]
    ).astype(np.float32)
    return Capture(names, img[..., :3], img[..., 3:], c2w, intr, {})


def test_report_of_a_synthetic_asset(tmp_path):
    """A textured synthetic asset scored at held-out cameras against its own renders with the light samples the
    report draws: the asset reproduces them exactly (the cameras, the light and the seeds are the ones measured),
    every row is finite, both baselines are below it, and the report's files are written."""
    from frng.apps.asset import AssetRenderer
    from frng.plan import catalog

    asset = synthetic_asset(tmp_path / "ball", textured=True)
    renderer = AssetRenderer(asset)
    env = np.full((16, 32, 3), 0.1, np.float32)
    env[:5] = 0.6  # lit from above; the renders stay below 1 (the metrics clip at 1 after compositing)
    inputs = _views(renderer, env, rig_cameras(6, DIST, FOV, RES), [f"in{i}" for i in range(6)], range(6))
    K = rig_cameras(1, DIST, FOV, RES)[0].intr
    held_cams = [
        type("C", (), {"c2w": camera.look_at(camera.spherical_to_cartesian(a, e, DIST)), "intr": K})
        for a, e in [(30, 10), (130, 25), (300, 40)]
    ]
    names = ["h0", "h1", "h2"]
    held = _views(renderer, env, held_cams, names, [catalog.derive_seed(5, "heldout", "ball", n) for n in names])
    held.info = {"skipped": {"h3": "h3.png: the mask is empty"}}
    result = capture_heldout.measure(renderer, held, inputs, env, seed=5, oid="ball")
    rows = result["rows"]
    assert len(rows) == 3 * 3 * 2 and capture_heldout.finite_rows(rows)
    m = capture_heldout.means(rows)
    print("\n" + m.round(3).to_string())
    for protocol in capture_heldout.PROTOCOLS:
        assert m.loc[("asset", protocol), "psnr"] == 100.0 and m.loc[("asset", protocol), "lpips"] < 1e-6
        for baseline in ("nearest-warped", "nearest"):
            assert m.loc[(baseline, protocol), "psnr"] < 40.0
    for protocol in capture_heldout.PROTOCOLS:  # measured: 23.9 vs 22.0 dB aligned, 23.7 vs 19.6 dB plain
        assert m.loc[("nearest-warped", protocol), "psnr"] > m.loc[("nearest", protocol), "psnr"]
    # the warp has the asset's silhouette, the unwarped view its own
    assert m.loc[("nearest-warped", "aligned"), "silhouette_iou"] > 0.95
    assert result["nearest"]["h0"][0] == "in0"
    line = capture_heldout.write_report(tmp_path / "ball", result, shown="ASSET")
    assert "\n" not in line and line.startswith("held-out: 3 views (1 skipped), asset PSNR ")
    assert "ASSET/heldout.md" in line
    md = (asset / "heldout.md").read_text()
    assert capture_heldout.BASELINE in md and "h3: h3.png: the mask is empty" in md and "nearest-warped" in md
    import pandas as pd

    df = pd.read_csv(asset / "heldout.csv")
    assert len(df) == 18 and set(df.method) == set(capture_heldout.METHODS)
    from frng import io

    sheet = io.read_png(asset / "heldout_sheet.png")
    assert sheet.shape[0] == 3 * sheet.shape[1] // 4


def test_report_with_no_scored_view(tmp_path):
    empty = Capture(
        [], np.zeros((0, RES, RES, 3)), np.zeros((0, RES, RES, 1)), np.zeros((0, 4, 4)), np.zeros((0, 4)), {}
    )
    empty.info = {"skipped": {"a": "why"}}
    result = capture_heldout.measure(None, empty, empty, np.ones((8, 16, 3), np.float32), seed=0)
    line = capture_heldout.write_report(tmp_path, result)
    assert line.startswith("held-out: no view could be scored (1 skipped)")
    assert (tmp_path / "heldout.csv").exists() and not (tmp_path / "heldout_sheet.png").exists()
