"""The held-out report of a capture: ``frng reconstruct ... --measure-heldout`` (issue 88).

When the views are chosen among more photos (``--cameras`` or ``--sfm`` with more than 10 photos, or ``--select
N``), the photos not chosen are held out; with ``--measure-heldout`` they are prepared as the views are (masked,
undistorted, cropped to the training field of view around the object's centre, resampled to the model's resolution;
:func:`frng.apps.capture.prepare` ``held_out=True``) and :func:`measure` scores the asset against them:

* **asset**: the asset rendered from its folder (:class:`frng.apps.asset.AssetRenderer`, as ``frng render-asset``)
  at each held-out photo's camera under the input light (``input_light.exr``: the estimate, or ``--light``), the
  light samples seeded per view;
* **nearest-warped** (the baseline): the input view whose camera direction (from the object's centre) is nearest
  the held-out camera's, backward-warped through the asset's depth: each pixel the asset covers at the held-out
  camera (rendered alpha > 0.5) is lifted to 3D at the asset's expected depth (depth / alpha), projected into that
  input view and its premultiplied RGBA sampled there (bilinear; outside the view is transparent). No occlusion
  test: a point the input view does not see takes the colour of what hides it. Pixels the asset does not cover are
  transparent, so the warp has the asset's silhouette;
* **nearest**: the same input view as it is (no warp; a weaker baseline, for scale).

Each is scored against the held-out photo by :func:`frng.metrics.evaluate_pair` under both protocols (``aligned``:
per-channel scale, PSNR / SSIM over the photo's mask; ``plain``: no scale, the whole image; LPIPS on the whole
composited image in both), over the config's ``eval.background``. :func:`write_report` writes ``heldout.csv`` (one
row per view, method and protocol), ``heldout.md`` (the means and what each method is) and ``heldout_sheet.png``
(per held-out view: photo | asset | nearest warped | nearest input) into the asset folder, and returns one line.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

METHODS = ("asset", "nearest-warped", "nearest")
PROTOCOLS = ("aligned", "plain")
COVERED = 0.5  # rendered alpha above which a pixel has a depth to warp by
BASELINE = (
    "the input view nearest in camera direction, backward-warped through the asset's depth at the held-out camera "
    "(no occlusion test; transparent where the asset does not cover)"
)


def nearest_inputs(held_c2w: np.ndarray, input_c2w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """For each held-out camera (V', 4, 4) the index of the input camera (V, 4, 4) whose direction from the origin
    (the object's centre) is nearest, and that angle in degrees: ((V',) int, (V',) float)."""
    unit = lambda c: c[:, :3, 3] / np.maximum(np.linalg.norm(c[:, :3, 3], axis=1, keepdims=True), 1e-12)  # noqa: E731
    cos = np.clip(unit(np.asarray(held_c2w)) @ unit(np.asarray(input_c2w)).T, -1.0, 1.0)
    idx = cos.argmax(1)
    return idx, np.degrees(np.arccos(cos[np.arange(len(idx)), idx]))


def warp(
    src_rgba: np.ndarray, src_c2w: np.ndarray, src_intr: np.ndarray, depth: np.ndarray, c2w: np.ndarray, intr
) -> np.ndarray:
    """Backward warp of a source view into another camera through a depth map.

    src_rgba (Hs, Ws, 4) premultiplied; src_c2w (4, 4), src_intr (4,) its OpenCV camera; depth (H, W) camera-frame
    z at the target camera c2w (4, 4), intr (4,), NaN or <= 0 where there is none. Returns (H, W, 4): the source
    sampled where each target pixel's 3D point projects (bilinear at pixel centres), 0 where there is no depth or
    the point falls outside the source (beyond its edge pixels' outer half) or behind it."""
    import torch
    from scipy import ndimage

    from frng import camera

    H, W = depth.shape
    t = lambda a: torch.as_tensor(np.asarray(a), dtype=torch.float64)  # noqa: E731
    uv = camera.pixel_centers(H, W, dtype=torch.float64)[None]
    z = np.nan_to_num(depth, nan=0.0)
    pts = camera.unproject(uv, t(z)[None], t(c2w)[None], t(intr)[None])  # (1, H, W, 3)
    suv, sz = camera.project(pts.reshape(-1, 3), t(src_c2w)[None], t(src_intr)[None])
    suv, sz = suv[0].numpy().reshape(H, W, 2), sz[0].numpy().reshape(H, W)
    Hs, Ws = src_rgba.shape[:2]
    coords = [suv[..., 1] - 0.5, suv[..., 0] - 0.5]  # the edge pixels reach half a pixel out, as the image does
    inside = (coords[0] >= -0.5) & (coords[0] <= Hs - 0.5) & (coords[1] >= -0.5) & (coords[1] <= Ws - 0.5)
    out = np.stack([ndimage.map_coordinates(src_rgba[..., c], coords, order=1, mode="nearest") for c in range(4)], -1)
    ok = (z > 0) & (sz > 0) & inside
    return np.where(ok[..., None], out, 0.0).astype(np.float32)


def asset_depth(renderer, c2w: np.ndarray, intr: np.ndarray, height: int, width: int) -> np.ndarray:
    """The asset's expected camera-frame depth (H, W) at one camera (c2w (4, 4), intr (4,)): the rasterizer's
    alpha-weighted depth over its alpha where the alpha is above :data:`COVERED`, NaN elsewhere."""
    import torch

    from frng.render import rasterize

    g = renderer.gaussians
    dev = g.means.device
    ones = torch.ones(len(g.means), 1, device=dev)
    f = lambda a: torch.as_tensor(np.asarray(a), dtype=torch.float32, device=dev)[None]  # noqa: E731
    with torch.no_grad():
        _, alpha, depth = rasterize(
            g.means, g.quats, g.scales, g.opacities, ones, f(c2w), f(intr), height, width, **renderer.raster.kwargs()
        )
    a, d = alpha[0, ..., 0].cpu().double().numpy(), depth[0, ..., 0].cpu().double().numpy()
    return np.where(a > COVERED, d / np.maximum(a, 1e-12), np.nan)


def measure(renderer, held, inputs, env: np.ndarray, *, seed: int, background=(1.0, 1.0, 1.0), oid: str = "") -> dict:
    """Score the asset and the baselines (module docstring) on the held-out views.

    renderer: an :class:`frng.apps.asset.AssetRenderer`; held, inputs: :class:`frng.apps.capture.Capture` (the
    held-out views and the input views, (V, R, R, 3) premultiplied RGB, (V, R, R, 1) alpha, cameras in the asset's
    frame); env (He, 2 He, 3): the input light in the asset's frame; seed: the light samples' master seed.
    Returns {"rows": [per view, method and protocol], "images": {view: {method: (R, R, 4)}}, "nearest": {view:
    (input name, angle deg)}, "skipped": {view: reason}}."""
    import torch

    from frng import metrics
    from frng.plan import catalog

    R = held.rgb.shape[1] if len(held.names) else 0
    rows, images, nearest = [], {}, {}
    idx, ang = nearest_inputs(held.c2w, inputs.c2w) if len(held.names) else ([], [])
    env_t = torch.from_numpy(np.ascontiguousarray(env, dtype=np.float32))
    in_rgba = np.concatenate([inputs.rgb, inputs.alpha], -1)
    for i, name in enumerate(held.names):
        j = int(idx[i])
        c2w, intr = held.c2w[i], held.intr[i]
        g = torch.Generator().manual_seed(catalog.derive_seed(seed, "heldout", oid, name))
        f = lambda a: torch.as_tensor(np.asarray(a), dtype=torch.float32)[None]  # noqa: E731
        with torch.no_grad():
            asset = renderer.render(env_t, f(c2w), f(intr), R, R, generator=g)[0].float().cpu().numpy()
        depth = asset_depth(renderer, c2w, intr, R, R)
        preds = {
            "asset": asset,
            "nearest-warped": warp(in_rgba[j], inputs.c2w[j], inputs.intr[j], depth, c2w, intr),
            "nearest": in_rgba[j].astype(np.float32),
        }
        gt = np.concatenate([held.rgb[i], held.alpha[i]], -1).astype(np.float32)
        images[name] = {"photo": gt, **preds}
        nearest[name] = (inputs.names[j], round(float(ang[i]), 2))
        for method, pred in preds.items():
            for protocol in PROTOCOLS:
                m = metrics.evaluate_pair(pred, gt, protocol=protocol, background=tuple(background))
                rows.append(
                    {
                        "view": name,
                        "method": method,
                        "protocol": protocol,
                        **{k: float(m[k]) for k in ("psnr", "ssim", "lpips", "silhouette_iou")},
                        "nearest_input": inputs.names[j],
                        "nearest_angle_deg": round(float(ang[i]), 2),
                    }
                )
    return {"rows": rows, "images": images, "nearest": nearest, "skipped": dict(held.info.get("skipped", {}))}


def means(rows: list[dict]):
    """Mean PSNR / SSIM / LPIPS / silhouette IoU per (method, protocol): a pandas DataFrame in :data:`METHODS`
    order."""
    import pandas as pd

    df = pd.DataFrame(rows)
    cols = ["psnr", "ssim", "lpips", "silhouette_iou"]
    out = df.groupby(["method", "protocol"])[cols].mean()
    order = [(m, p) for m in METHODS for p in PROTOCOLS if (m, p) in out.index]
    return out.reindex(order)


def sheet(images: dict, background=(1.0, 1.0, 1.0), tile: int = 96) -> np.ndarray:
    """Per held-out view one row: photo | asset | nearest warped | nearest input (over ``background``, sRGB,
    upscaled to about ``tile`` px). uint8 (rows x R', 4 x R', 3)."""
    from frng import io

    rows = []
    for views in images.values():
        tiles = [io.srgb_encode(io.composite(views[k], tuple(background))) for k in ("photo", *METHODS)]
        k = max(1, tile // tiles[0].shape[0])
        rows.append(np.concatenate([np.kron(t_, np.ones((k, k, 1))) for t_ in tiles], 1))
    return (np.clip(np.concatenate(rows, 0), 0, 1) * 255 + 0.5).astype(np.uint8)


def summary_line(result: dict, folder: str | Path) -> str:
    """The one line ``frng reconstruct --measure-heldout`` prints."""
    n, skipped = len(result["images"]), len(result["skipped"])
    skip = f" ({skipped} skipped)" if skipped else ""
    if not n:
        return f"held-out: no view could be scored{skip}; see {Path(folder) / 'heldout.md'}"
    m = means(result["rows"])
    a, b = m.loc[("asset", "aligned")], m.loc[("nearest-warped", "aligned")]
    plain_a, plain_b = m.loc[("asset", "plain"), "psnr"], m.loc[("nearest-warped", "plain"), "psnr"]
    return (
        f"held-out: {n} views{skip}, asset PSNR {a.psnr:.2f} dB / SSIM {a.ssim:.3f} / LPIPS {a.lpips:.3f} "
        f"(plain PSNR {plain_a:.2f}) vs nearest input warped by the asset's depth {b.psnr:.2f} / {b.ssim:.3f} / "
        f"{b.lpips:.3f} (plain {plain_b:.2f}) -> {Path(folder) / 'heldout.md'}"
    )


def report_markdown(result: dict, line: str) -> str:
    """``heldout.md``: what was measured, the means table, each view's nearest input, the skipped photos."""
    lines = [
        "# Held-out views",
        "",
        "The photos not chosen as views, prepared as the views are, against the asset rendered at their cameras "
        "under the input light (`input_light.exr`) and two baselines (`frng.apps.capture_heldout`):",
        "",
        "- `asset`: the asset, rendered from this folder as `frng render-asset` does;",
        f"- `nearest-warped`: {BASELINE};",
        "- `nearest`: that input view as it is (no warp).",
        "",
        "Protocols (`frng.metrics`): `aligned` scales each channel to the photo (least squares over its mask) and "
        "takes PSNR / SSIM over the mask; `plain` neither. LPIPS on the whole composited image. Per view: "
        "`heldout.csv`; photo | asset | nearest warped | nearest: `heldout_sheet.png`.",
        "",
        line,
        "",
    ]
    if result["rows"]:
        lines += [means(result["rows"]).reset_index().round(4).to_markdown(index=False), ""]
        lines += ["| held-out view | nearest input | angle (deg) |", "|---|---|---|"]
        lines += [f"| {v} | {n} | {a:.1f} |" for v, (n, a) in result["nearest"].items()]
        lines.append("")
    if result["skipped"]:
        lines += ["Skipped (not scored):", ""] + [f"- {k}: {why}" for k, why in result["skipped"].items()] + [""]
    return "\n".join(lines)


def write_report(folder: str | Path, result: dict, background=(1.0, 1.0, 1.0), shown: str | Path | None = None) -> str:
    """``heldout.csv``, ``heldout.md`` and (with scored views) ``heldout_sheet.png`` into ``folder`` (the staged
    asset folder); returns the summary line, which names ``shown`` (the asset folder the user gave; default
    ``folder``)."""
    import pandas as pd

    from frng import io

    folder = Path(folder)
    line = summary_line(result, folder if shown is None else shown)
    cols = ["view", "method", "protocol", "psnr", "ssim", "lpips", "silhouette_iou", "nearest_input"]
    pd.DataFrame(result["rows"], columns=[*cols, "nearest_angle_deg"]).to_csv(folder / "heldout.csv", index=False)
    (folder / "heldout.md").write_text(report_markdown(result, line))
    if result["images"]:
        io.write_png(folder / "heldout_sheet.png", sheet(result["images"], background))
    return line


def finite_rows(rows: list[dict]) -> bool:
    """Whether every score of ``rows`` is a finite number."""
    return all(math.isfinite(r[k]) for r in rows for k in ("psnr", "ssim", "lpips", "silhouette_iou"))


__all__ = ["BASELINE", "METHODS", "asset_depth", "measure", "means", "nearest_inputs", "warp", "write_report"]
