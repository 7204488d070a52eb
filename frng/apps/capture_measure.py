"""Measurement of the capture path: ``frng reconstruct`` + ``frng render-asset`` on a curated test object, scored
against ``frng relight``'s ``full`` run (``frng reconstruct --measure OBJ...``, :mod:`frng.commands.reconstruct`).

:func:`export_object` writes a curated object's input views as a user's capture would hand them (sRGB PNGs, a camera
file, the light); :func:`measure` reconstructs them under each setting (EXR + cameras or PNG + the paper rig, the
light given or estimated: :func:`frng.apps.reconstruct.reconstruct`) and scores the renders with the same target
lights, views, light-sample seeds and metrics as the pipeline.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from frng import io
from frng.apps.capture_errors import CaptureError
from frng.apps.reconstruct import default_model, reconstruct
from frng.render import envmap


def _rot_z(deg: float) -> np.ndarray:
    c, s_ = math.cos(math.radians(deg)), math.sin(math.radians(deg))
    R = np.eye(4)
    R[:2, :2] = [[c, -s_], [s_, c]]
    return R


def export_object(config, oid: str, out: Path, views: int = 6) -> Path:
    """A curated object's first ``views`` input views (input light) as straight-alpha sRGB PNGs
    (``{out}/images/{view}.png``), their cameras (``{out}/cameras.json``, frng entries) and the input light
    (``{out}/light.exr``). Returns ``out``."""
    from frng.plan.layout import Layout

    L = Layout(config.results)
    try:
        meta = io.read_json(L.object_meta(oid))
    except (FileNotFoundError, ValueError) as e:
        raise CaptureError(f"{L.object_meta(oid)}: cannot read object metadata ({e})") from e
    light = meta["input_lights"][0]
    (out / "images").mkdir(parents=True, exist_ok=True)
    cams = meta["views"]["inputs"][:views]
    for cam in cams:
        rgba = io.read_rgba(L.object_image(oid, "inputs", light, cam["name"]), require_alpha=True)
        a = np.clip(rgba[..., 3:4], 0, 1)
        rgb = np.where(a > 1e-6, rgba[..., :3] / np.maximum(a, 1e-6), 0.0)
        io.write_png(out / "images" / f"{cam['name']}.png", np.concatenate([io.srgb_encode(rgb), a], -1))
    io.write_json(out / "cameras.json", {"cameras": cams})
    envmap.write(out / "light.exr", envmap.read(L.envmap(light)))
    return out


def measure(config, oid: str, work: str | Path, views: int = 6, settings=None) -> list[dict]:
    """Score ``frng reconstruct`` + ``frng render-asset`` on a curated test object against ``frng relight``'s ``full``
    run: the same target lights, target views, light-sample seeds and metrics (``eval`` protocol).

    Settings (``settings``: a subset of the names): ``relight`` (the reference: ``{results}/relight/full/{oid}``),
    ``exr+cameras/known`` (the first ``views`` input EXRs, cameras from meta.json, the input light given: an oracle,
    since ``frng relight`` estimates it, the paper's task),
    ``png+rig/known`` (the same views exported as 8-bit PNGs, ``--rig paper``, no camera file; the object's rig
    starts at azimuth a0, the paper rig at 0, so the given light, the target cameras and the target lights are
    rotated by -a0 about Z into the asset's frame), and both again with the light estimated (``.../estimated``).
    Returns one row per (setting, light, view): psnr, ssim, lpips (the config's ``eval.protocol``) and psnr_plain
    (no colour alignment: shows colour casts of the estimated light that the aligned protocol forgives)."""
    import torch

    from frng import metrics
    from frng.apps.asset import AssetRenderer
    from frng.plan import catalog
    from frng.plan.layout import Layout

    cfg = config
    L = Layout(cfg.results)
    work = Path(work)
    meta = io.read_json(L.object_meta(oid))
    light_in = meta["input_lights"][0]
    a0 = float(meta["views"]["inputs"][0]["azimuth_deg"])
    tc2w = np.array([c["c2w"] for c in meta["views"]["targets"]])
    tintr = np.array([c["intrinsics"] for c in meta["views"]["targets"]])
    tnames = [c["name"] for c in meta["views"]["targets"]]
    H, W = int(meta["views"]["targets"][0]["height"]), int(meta["views"]["targets"][0]["width"])
    lights = list(meta["target_lights"])
    exr = work / "exr"
    exr.mkdir(parents=True, exist_ok=True)
    for cam in meta["views"]["inputs"][:views]:
        dst = exr / f"{cam['name']}.exr"
        if not dst.exists():
            dst.symlink_to(Path(L.object_image(oid, "inputs", light_in, cam["name"])).resolve())
    png = export_object(cfg, oid, work / "png", views) / "images"
    rig_light = work / "light_rig.exr"
    envmap.write(rig_light, envmap.rotate_z(envmap.read(L.envmap(light_in)), -a0))
    every = {
        "exr+cameras/known": (exr, dict(cameras=L.object_meta(oid), light=L.envmap(light_in)), 0.0),
        "png+rig/known": (png, dict(rig="paper", light=rig_light), -a0),
        "exr+cameras/estimated": (exr, dict(cameras=L.object_meta(oid)), 0.0),
        "png+rig/estimated": (png, dict(rig="paper"), -a0),
    }
    rows = []

    def score(setting, light, images):
        for name, img in zip(tnames, images):
            gt = io.read_rgba(L.object_image(oid, "targets", light, name), require_alpha=True)
            bg = tuple(cfg.eval.background)
            m = metrics.evaluate_pair(img, gt, protocol=cfg.eval.protocol, background=bg)
            plain = metrics.evaluate_pair(img, gt, protocol="plain", background=bg)
            rows.append(
                {
                    "setting": setting,
                    "object": oid,
                    "light": light,
                    "view": name,
                    **{k: m[k] for k in ("psnr", "ssim", "lpips")},
                    "protocol": cfg.eval.protocol,
                    "psnr_plain": plain["psnr"],
                }
            )

    if settings is None or "relight" in settings:
        for light in lights:
            score(
                "relight",
                light,
                [
                    io.read_rgba(Path(L.relight_image(default_model(L).parent.name, oid, light, n)), require_alpha=True)
                    for n in tnames
                ],
            )
    for setting, (images, kw, rot) in every.items():
        if settings is not None and setting not in settings:
            continue
        asset = work / setting.replace("/", "_")
        reconstruct(images, asset, cfg, name=oid, allow_outside=True, **kw)  # exr/: symlinks into the results
        r = AssetRenderer(asset)
        R = _rot_z(rot)
        c2w = torch.tensor(np.einsum("ij,vjk->vik", R, tc2w), dtype=torch.float32)
        intr = torch.tensor(tintr, dtype=torch.float32)
        for light in lights:
            env = envmap.read(L.envmap(light))
            env = envmap.rotate_z(env, rot) if rot else env
            g = torch.Generator().manual_seed(catalog.derive_seed(cfg.seed, "relight-frng", oid, light))
            out = r.render(torch.from_numpy(env), c2w, intr, H, W, generator=g).numpy()
            score(setting, light, list(out))
    return rows


__all__ = ["export_object", "measure"]
