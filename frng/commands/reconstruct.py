"""Stage ``frng reconstruct --images DIR --out ASSET`` (no rule: run by hand on your own photos): 2-10 photos of one
object -> a relightable asset folder (:mod:`frng.apps.asset`) that ``frng render-asset`` relights without the model.

Images, masks, cameras, framing and the light estimate: :mod:`frng.apps.capture`. The model is a trained pipeline's:
``--model`` (default ``{results}/models/plus/model.pt`` (F-RNG+) of the config, else ``models/full/model.pt``) and ``--config`` (default: the
``config.yaml`` recorded in the results folder the model lives in, ``{results}/models/full/model.pt`` ->
``{results}/config.yaml``), which gives the architecture, the resolution, the training rig and the priors.
``--cameras`` reads transforms.json, OpenCV files, COLMAP models, LLFF and IDR / NeuS cameras
(:mod:`frng.apps.camera_formats`); ``--sfm`` finds them from the photos by structure from motion on the CPU
(:mod:`frng.apps.sfm`); with more photos than the model takes it chooses the views (``--select N``,
:mod:`frng.apps.capture_frame`) and prints which. Photos without masks on a textured background are segmented
(:mod:`frng.apps.masks`).
``--export-object OBJ`` instead writes a curated object's input views as plain PNGs into ``{out}/images/`` (+
``{out}/cameras.json`` and its input light ``{out}/light.exr``): files to try the command on.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path


def configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--images",
        help="folder of 2-10 images (PNG, JPEG, EXR; more with --cameras: the views are chosen), or one grid image "
        "with --grid",
    )
    parser.add_argument("--out", required=True, help="asset folder to write (with --export-object: a folder)")
    parser.add_argument(
        "--masks",
        help="folder of mask images (default: alpha, else a keyed uniform background, else GrabCut segmentation "
        "seeded by the image centre or the --sfm points; frng.apps.masks)",
    )
    cams = parser.add_mutually_exclusive_group()
    cams.add_argument(
        "--cameras",
        help="transforms.json (NeRF, with k1 k2 p1 p2), an OpenCV camera file (JSON/YAML), a COLMAP model (folder "
        "or its cameras/images files, text or binary), LLFF poses_bounds.npy or IDR/NeuS cameras_sphere.npz",
    )
    cams.add_argument(
        "--rig", choices=["paper"], help="the paper's 6-view rig (default when neither --cameras nor --sfm)"
    )
    cams.add_argument(
        "--sfm",
        action="store_true",
        help="no camera file: find the cameras from the photos by structure from motion on the CPU (pycolmap: "
        "SIFT, exhaustive matching, incremental mapping; 3+ overlapping photos, 20-100 around the object is "
        "best; frng.apps.sfm)",
    )
    parser.add_argument(
        "--select",
        type=int,
        metavar="N",
        help="with --cameras or --sfm: choose N views among the photos (default: 6 when there are more than 10 "
        "photos); the others are held out (frng.apps.capture_frame)",
    )
    parser.add_argument("--light", help="the photos' light as an equirect map (EXR/HDR, 2:1); default: estimated")
    parser.add_argument(
        "--light-colour",
        choices=["neutral", "fit"],
        default="neutral",
        help="estimated light: grey on average (grey world) or its fitted colour",
    )
    parser.add_argument("--grid", help="split one image holding a ROWSxCOLS grid of views, e.g. 2x3")
    parser.add_argument(
        "--framing",
        choices=["auto", "keep", "object"],
        default="auto",
        help="rig photos: keep the framing (square crop) or crop around the object (frng.apps.capture)",
    )
    parser.add_argument("--name", help="object id recorded in the asset (default: the images folder's name)")
    parser.add_argument(
        "--model", help="F-RNG model file (default {results}/models/plus/model.pt, F-RNG+, else models/full/model.pt)"
    )
    parser.add_argument("--config", help="pipeline config (default: config.yaml of the model's results folder)")
    parser.add_argument("--device", help="override the config's device (cpu, cuda, auto)")
    parser.add_argument(
        "--export-object",
        metavar="OBJ",
        help="instead: write curated object OBJ's input views as PNGs (+ cameras.json, light.exr)",
    )
    parser.add_argument(
        "--force",
        action="store_true",
        help="replace a non-empty --out that is not a previous asset (only the asset's files are replaced; "
        "other files there are kept)",
    )
    parser.add_argument(
        "--allow-outside",
        action="store_true",
        help="read photos and masks that are symlinks out of their folders (refused by default)",
    )
    parser.add_argument("--views", type=int, default=6, help="with --export-object: how many input views")
    parser.add_argument(
        "--measure-heldout",
        action="store_true",
        help="with --cameras or --sfm and more photos than views: render the asset at the held-out photos' cameras "
        "under the input light and score it and a baseline (the nearest input view warped by the asset's depth) "
        "against them; {out}/heldout.md, heldout.csv, heldout_sheet.png (frng.apps.capture_heldout)",
    )
    parser.add_argument(
        "--measure",
        metavar="OBJ",
        nargs="+",
        help="instead: score reconstruct + render-asset on curated test objects against `frng "
        "relight` (frng.apps.capture_measure.measure); writes {out}/measure.csv and prints the means (your own "
        "photos: --measure-heldout)",
    )


def resolve_config(config: str | None, model: str | None):
    """The config to use: ``--config``, else the one recorded beside the model (``{results}/config.yaml``)."""
    from frng.apps.capture import CaptureError
    from frng.apps.reconstruct import results_of_model
    from frng.plan import config as frng_config
    from frng.typedconfig import typed

    if config is None:
        if model is None:
            raise CaptureError(
                "give --config (a trained pipeline's config) or --model (its config.yaml is read "
                "from the model's results folder)"
            )
        from frng.plan.layout import Layout

        config = Layout(results_of_model(Path(model))).config()
        if not Path(config).exists():
            raise CaptureError(f"{config}: no recorded config beside the model {model}; pass --config")
    return typed(frng_config.load(config))


def measure_table(config, oids: list[str], out: Path) -> str:
    """:func:`frng.apps.capture_measure.measure` over ``oids``; per-image rows to ``{out}/measure.csv``; returns the per-setting
    means (over objects, lights and views) with the PSNR difference to ``relight`` as Markdown."""
    import pandas as pd

    from frng.apps.capture_measure import measure

    rows = []
    for oid in oids:
        rows += measure(config, oid, out / oid)
    df = pd.DataFrame(rows)
    df.to_csv(out / "measure.csv", index=False)
    order = ["relight", "exr+cameras/known", "png+rig/known", "exr+cameras/estimated", "png+rig/estimated"]
    mean = df.groupby("setting")[["psnr", "ssim", "lpips", "psnr_plain"]].mean().reindex(order)
    mean.insert(1, "dpsnr", mean["psnr"] - mean.loc["relight", "psnr"])
    mean["dpsnr_plain"] = mean["psnr_plain"] - mean.loc["relight", "psnr_plain"]
    return (
        f"{len(oids)} object(s), {len(df) // len(order)} images per setting, {df['protocol'].iloc[0]} protocol\n"
        + mean.round(3).to_markdown()
    )


def run(args: argparse.Namespace) -> int:
    from frng import cli
    from frng.apps.asset import AssetError
    from frng.apps.capture import CaptureError, parse_grid
    from frng.apps.capture_measure import export_object
    from frng.apps.reconstruct import reconstruct

    try:
        config = resolve_config(args.config, args.model)
        if args.measure:
            print(measure_table(config, args.measure, Path(args.out)))
            return 0
        if args.export_object:  # staged: a failure leaves --out as it was; a foreign --out needs --force
            from frng import confine

            try:
                with confine.staged_output(args.out, "reconstruct --export-object", args.force) as stage:
                    export_object(config, args.export_object, stage, args.views)
            except confine.OutputError as e:
                raise CaptureError(str(e)) from None
            print(args.out)
            return 0
        if not args.images:
            raise CaptureError("--images is required")
        record = reconstruct(
            args.images,
            args.out,
            config,
            model=args.model,
            masks=args.masks,
            cameras=args.cameras,
            rig=args.rig,
            light=args.light,
            grid=parse_grid(args.grid),
            framing=args.framing,
            name=args.name,
            device=args.device,
            light_colour=args.light_colour,
            force=args.force,
            allow_outside=args.allow_outside,
            select=args.select,
            sfm=args.sfm,
            measure_heldout=args.measure_heldout,
        )
    except (CaptureError, AssetError) as e:
        if cli.DEBUG:  # `frng --debug`: the traceback
            raise
        print(f"frng reconstruct: error: {e}")
        return 2
    light = record["light"]
    what = (
        light["source"]
        if light["source"] != "estimated"
        else f"estimated (SH fit, relative rms {light['relative_rms']:.2f})"
    )
    print(
        f"reconstruct {record['object_id']}: {len(record['views'])} views ({', '.join(sorted(set(record['masks'])))}"
        f" masks, cameras {record['cameras']}), light {what} -> {args.out}"
    )
    if "selection" in record:
        print(record["selection"]["summary"])
    if "heldout" in record:
        print(record["heldout"])
    print(json.dumps(record["timing_s"]))
    return 0
