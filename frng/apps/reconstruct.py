"""Reconstruction: a prepared capture (:func:`frng.apps.capture.prepare`) -> a relightable asset folder
(``frng reconstruct``, :mod:`frng.commands.reconstruct`).

:func:`reconstruct` checks every input (images, masks, cameras, light map, model files) before anything is loaded
or written, runs the IDM, the light estimate (:func:`frng.apps.capture.estimate_light`, unless ``--light`` gives the
map), the backbone and F-RNG's reconstruction (:meth:`frng.model.composed.FRNG.reconstruct`), and writes the asset
(:func:`frng.apps.asset.save_asset`) with ``input_light.exr`` and ``contact_sheet.png`` (:func:`contact_sheet`).
The model is a trained pipeline's (:func:`default_model`: F-RNG+ where trained, else the paper's ``full``).

What a capture is and how the photos become views on the training rig: :mod:`frng.apps.capture`; measuring this
path on a curated test object against ``frng relight``: :mod:`frng.apps.capture_measure`.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from frng import confine, io
from frng.apps import capture_frame
from frng.apps.capture import LIGHT_COLOUR, Capture, estimate_light, prepare, read_light
from frng.apps.capture_errors import CaptureError
from frng.render import envmap


def default_model(L) -> Path:
    """The model ``frng reconstruct`` uses without ``--model``: F-RNG+ (``{results}/models/plus/model.pt``) where it
    was trained, else the paper's F-RNG (``full``). Measured on the default tier, the photos' light unknown to both
    (2026-12-05, 21 objects): F-RNG+ +1.45 dB [1.13, 1.80] over the backbone, the paper's form -0.32 [-0.69, 0.03],
    its colours far off (docs/results.md). ``L``: the results folder's :class:`frng.plan.layout.Layout`."""
    from frng.plan.layout import TrainingFolder

    plus = Path(TrainingFolder(L.model_dir("plus")).model())
    return plus if plus.exists() else Path(TrainingFolder(L.model_dir("full")).model())


def results_of_model(model: Path) -> Path:
    """``{results}/models/{variant}/model.pt`` -> ``{results}`` (where its ``config.yaml`` is recorded)."""
    return Path(model).resolve().parent.parent.parent


def reconstruct(
    images,
    out,
    config,
    *,
    model=None,
    masks=None,
    cameras=None,
    rig=None,
    light=None,
    grid=None,
    framing: str = "auto",
    name: str | None = None,
    device: str | None = None,
    light_colour: str = LIGHT_COLOUR,
    force: bool = False,
    allow_outside: bool = False,
    select: int | None = None,
    sfm: bool = False,
    measure_heldout: bool = False,
) -> dict:
    """Photos -> an asset folder ``out`` (:mod:`frng.apps.asset`, plus ``input_light.exr`` and ``contact_sheet.png``).

    ``config``: the pipeline config the model was trained with (architecture, resolution, rig, priors' files);
    ``model``: the F-RNG model file (default :func:`default_model`: F-RNG+ where trained, else ``full``). The backbone and the IDM are the
    config's (``{results}/backbone/model.pt``, the configured IDM). ``name``: the object id (default: the images
    folder's name); with ``light`` the light's name is the map's stem. Returns the asset's ``capture`` record.
    Everything is checked (images, masks, cameras, light map, model files) before anything is loaded or written.

    ``out`` is written through :func:`frng.confine.staged_output`: a non-empty folder that is not a previous asset
    (of ``frng reconstruct``) is refused unless ``force``, which replaces only the asset's files and keeps the
    others; a failure leaves the previous ``out`` whole. ``allow_outside``: read photos and masks that are symlinks
    out of their folders. ``select``: how many views to choose among the photos (:func:`prepare`). ``sfm``: the
    cameras from structure from motion (:mod:`frng.apps.sfm`), its scratch folder where ``out``'s staging folder
    goes (inside ``out`` when it exists, else beside it) and removed afterwards. ``measure_heldout``: score the asset
    and a baseline on the held-out photos (:mod:`frng.apps.capture_heldout`; ``heldout.csv``, ``heldout.md`` and
    ``heldout_sheet.png`` in ``out``; the record's ``heldout`` holds the summary line); needs held-out photos
    (``cameras`` or ``sfm`` with the views chosen among more photos)."""
    import torch

    from frng.apps.asset import RIG_KEY, render_settings, save_asset
    from frng.apps.relight import Timer, backbone_views
    from frng.device import resolve_device
    from frng.plan.layout import Layout

    cfg = config
    rc = cfg.render
    try:
        confine.check_output(out, "reconstruct", force, recognise=is_asset_folder)
    except confine.OutputError as e:
        raise CaptureError(str(e)) from None
    if measure_heldout and cameras is None and not sfm:
        raise CaptureError(
            f"{images}: --measure-heldout scores the photos held out of the views: give --cameras or --sfm and more "
            f"photos than views (more than 10, or --select N)"
        )
    if sfm:  # before minutes of structure from motion
        L0 = Layout(cfg.results)
        _check_models(Path(model) if model is not None else default_model(L0), Path(L0.backbone_model()))
    cap = prepare(
        images,
        resolution=rc.resolution,
        distance=rc.camera_distance,
        fov_deg=rc.fov_deg,
        masks=masks,
        cameras=cameras,
        rig=rig,
        grid=grid,
        framing=framing,
        allow_outside=allow_outside,
        select=select,
        sfm=sfm,
        work=next((d for d in (Path(out), Path(out).parent) if d.is_dir()), None),
        held_out=measure_heldout,
    )
    if measure_heldout and cap.held_out is None:
        raise CaptureError(
            f"{images}: --measure-heldout: no photo is held out ({len(cap.names)} photos, all of them views); give "
            f"more photos than views (more than 10, or --select N with N below the number of photos)"
        )
    if float(np.max(cap.rgb, initial=0.0)) < 1.0 / 4096:  # an asset lit by an all-zero light, else
        import sys

        print(
            f"warning: {images}: every photo is black inside its mask (max linear value "
            f"{float(np.max(cap.rgb, initial=0.0)):.2g}); the light estimate and the asset will be black",
            file=sys.stderr,
        )
    env_given = read_light(light) if light is not None else None
    if env_given is not None:  # given in the user's frame; the asset's is upright (frng.apps.capture_frame)
        env_given = capture_frame.light_to_asset(env_given, cap.info["world_to_asset"])
    L = Layout(cfg.results)
    model = Path(model) if model is not None else default_model(L)
    backbone_path = Path(L.backbone_model())
    _check_models(model, backbone_path)
    oid = name or (Path(images).resolve().stem if Path(images).is_file() else Path(images).resolve().name)
    dev = resolve_device(device or cfg.device)

    from frng.model.composed import FRNG
    from frng.priors import build_idm, load_backbone

    views = cap.views()
    timing = {}
    with torch.no_grad():
        net = FRNG.load(model, dev).set_inference_shading(cfg.shading)
        if net.cfg.head != "neural" or net.decoder is None:
            raise CaptureError(f"{model}: a {net.cfg.head!r} model has no neural decoder; reconstruct needs one")
        idm = build_idm(cfg.idm, cfg.backbone, cfg.results, dev)
        backbone = load_backbone(backbone_path, dev)
        with Timer(dev) as t_idm:
            pri = idm.priors(oid, views)
        if env_given is None:
            h = max(8, int(cfg.envmaps.width) // 2)
            with Timer(dev) as t_light:
                env, est = estimate_light(
                    cap.rgb, cap.alpha, pri.albedo.numpy(), pri.normal.numpy(), h, colour=light_colour
                )
            light_info = {"source": "estimated", **est}
            timing["light_s"] = t_light.s
        else:
            env = env_given
            light_info = {"source": str(light)}
        env_t = torch.from_numpy(np.ascontiguousarray(env))
        with Timer(dev) as t_bb:
            bv = backbone_views(cfg.seed, backbone, oid, views, dev)
        images_t = torch.cat([views.rgb, views.alpha], -1).to(dev)
        with Timer(dev) as t_rec:
            # the paper's task: the model estimates the photos' light itself (the same fit as the record's); a
            # light the user gives (--light) is passed on
            told = None if env_given is None else env_t.to(dev)
            rec = net.reconstruct(bv, 0, pri.to(dev) if net.cfg.uses_priors else None, images_t, input_env=told)
    timing |= {"idm_s": t_idm.s, "backbone_s": t_bb.s, "frng_s": t_rec.s}
    record = {
        **cap.info,
        "object_id": oid,
        "views": list(cap.names),
        "light": light_info,
        "cameras_normalised": [
            {
                "name": n_,
                "c2w": c.tolist(),
                "intrinsics": k.tolist(),
                "width": int(rc.resolution),
                "height": int(rc.resolution),
            }
            for n_, c, k in zip(cap.names, cap.c2w, cap.intr)
        ],
        "model": str(model),
        "timing_s": timing,
    }
    feats = rec.features.detach().float().cpu()
    preview = (feats[:, 3:6].clamp_min(0) * math.pi).clamp(0, 1) if net.decoder.cosine else None
    meta = {
        "object_id": oid,
        "source_views": list(cap.names),
        "decoder": net.decoder_meta(),
        **render_settings(net.raster_cfg, net.shading_cfg, net.cfg.max_radius_px),
        RIG_KEY: {
            "camera_distance": float(rc.camera_distance),
            "fov_deg": float(rc.fov_deg),
            "resolution": int(rc.resolution),
        },
        "variant": getattr(net, "meta", {}).get("variant", "full"),
        "capture": record,
    }
    sheet = contact_sheet(cap, env)
    g = rec.gaussians
    from frng.gaussians import Gaussians

    gauss = Gaussians(*(t.detach().float().cpu() for t in (g.means, g.quats, g.scales, g.opacities)), feats)
    try:
        with confine.staged_output(out, "reconstruct", force, recognise=is_asset_folder) as stage:
            save_asset(
                stage,
                gauss,
                feats,
                net.asset_weights(),
                meta,
                preview_rgb=preview,
                extra_files={
                    "input_light.exr": lambda p: envmap.write(p, env),
                    "contact_sheet.png": lambda p: io.write_png(p, sheet),
                },
            )
            if measure_heldout:  # the asset as written, rendered from the staged folder
                from frng.apps import capture_heldout
                from frng.apps.asset import AssetRenderer

                bg = tuple(cfg.eval.background)
                result = capture_heldout.measure(
                    AssetRenderer(stage, device=dev), cap.held_out, cap, env, seed=cfg.seed, background=bg, oid=oid
                )
                record["heldout"] = capture_heldout.write_report(stage, result, bg, shown=out)
    except confine.OutputError as e:
        raise CaptureError(str(e)) from None
    return record


def _check_models(model: Path, backbone: Path) -> None:
    for f, what in ((model, "F-RNG model"), (backbone, "backbone model")):
        if not f.exists():
            raise CaptureError(f"{f}: {what} missing (train the pipeline, or pass --model / --config)")


def is_asset_folder(folder: Path) -> bool:
    """Whether ``folder`` holds an asset (its ``asset.json`` says ``frng-asset``): a previous ``frng reconstruct``
    output written before output folders carried a manifest."""
    try:
        return io.read_json(Path(folder) / "asset.json").get("format") == "frng-asset"
    except (OSError, ValueError, AttributeError):
        return False


def contact_sheet(cap: Capture, env: np.ndarray, tile: int = 96) -> np.ndarray:
    """Rows: the views (over white), their masks, the input light (tonemapped, mean at mid grey). uint8 RGB."""
    V = len(cap.names)
    up = lambda im: np.kron(im, np.ones((max(1, tile // im.shape[0]), max(1, tile // im.shape[0]), 1)))  # noqa
    views = [up(io.srgb_encode(io.composite(np.concatenate([r, a], -1)))) for r, a in zip(cap.rgb, cap.alpha)]
    masks = [up(np.repeat(a, 3, -1)) for a in cap.alpha]
    th, tw = views[0].shape[:2]
    sheet_w = V * tw
    lum = float(envmap.luminance(env).mean()) or 1.0
    light = io.srgb_encode(env * (0.18 / lum))
    lw = min(sheet_w, 2 * th * 2)
    k = max(1, lw // light.shape[1])
    light = np.kron(light, np.ones((k, k, 1)))[:, :sheet_w]
    row3 = np.ones((light.shape[0], sheet_w, 3), np.float32)
    row3[:, : light.shape[1]] = light
    sheet = np.concatenate([np.concatenate(views, 1), np.concatenate(masks, 1), row3], 0)
    return (np.clip(sheet, 0, 1) * 255 + 0.5).astype(np.uint8)


__all__ = ["contact_sheet", "default_model", "is_asset_folder", "reconstruct", "results_of_model"]
