"""``frng bench export``: how well plain 3D Gaussian splatting holds a trained tier's relit assets, i.e. the fit
``frng export-asset`` reports, measured over every asset of a results folder (:mod:`frng.apps.export`).

For each asset ``{results}/relight/{model}/{object}/asset`` (the assets ``frng relight`` saved) and each of that
object's relighting lights (the run folders beside it, whose maps are ``{results}/envmaps/{light}.exr``; the first
``--lights`` of them), the asset is baked as ``frng export-asset`` bakes it (:func:`frng.apps.export.bake`: the
decoder's display colour at :data:`~frng.apps.export.FIT_DIRECTIONS` directions per Gaussian, degree-3 SH fitted
by least squares) and the fit is scored on :data:`~frng.apps.export.HELDOUT_DIRECTIONS` other directions
(opacity-weighted PSNR of the clamped SH colour against the decoder's). No file is exported.

Writes into ``--out``: ``export.csv`` (model, object, light, Gaussians, fit PSNR, seconds; a row as each asset is
measured) and ``summary.md`` (per model: assets, min / median / mean fit PSNR, the worst asset, seconds per asset).
With ``--floor DB`` it exits 1 when an asset's fit falls below it (the floor the export's documentation states).
"""

from __future__ import annotations

import argparse
import csv
import statistics
import sys
import time
from pathlib import Path

COLUMNS = ("model", "object", "light", "gaussians", "fit_psnr_db", "seconds")


def configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("results", type=Path, help="a results folder with relit assets (relight/{model}/{obj}/asset)")
    parser.add_argument("--models", nargs="+", help="model variants under relight/ (default: every one with assets)")
    parser.add_argument("--objects", nargs="+", help="object ids (default: every object with an asset)")
    parser.add_argument("--lights", type=int, default=1, help="lights per object: its first N relighting lights")
    parser.add_argument("--exposure", type=float, default=0.0, help="exposure in EV, as export-asset's --exposure")
    parser.add_argument("--out", type=Path, required=True, help="folder for export.csv and summary.md")
    parser.add_argument("--floor", type=float, help="exit 1 when an asset's fit PSNR (dB) is below this")


def assets(results: Path, models: list[str] | None, objects: list[str] | None, lights: int) -> list[tuple]:
    """(model, object, light, asset folder, map path) for every asset and its first ``lights`` lights with a map,
    sorted; a named model or object without assets is an error naming it."""
    relight = results / "relight"
    if not relight.is_dir():
        raise FileNotFoundError(f"{relight}: no relight folder (run the pipeline's relight rules first)")
    found = sorted(p.parent.parent for p in relight.glob("*/*/asset/asset.json"))  # object folders
    jobs = []
    for model in models or sorted({p.parent.name for p in found}):
        have = [p for p in found if p.parent.name == model]
        if not have:
            raise FileNotFoundError(f"{relight / model}: no assets for model '{model}'")
        for obj in objects or [p.name for p in have]:
            folder = relight / model / obj
            if folder not in have:
                raise FileNotFoundError(f"{folder / 'asset'}: no asset for object '{obj}' of model '{model}'")
            runs = sorted(d.name for d in folder.iterdir() if (results / "envmaps" / f"{d.name}.exr").is_file())
            if not runs:
                raise FileNotFoundError(f"{folder}: no relighting light with a map in {results / 'envmaps'}")
            jobs += [
                (model, obj, light, folder / "asset", results / "envmaps" / f"{light}.exr") for light in runs[:lights]
            ]
    return jobs


def summary(rows: list[dict]) -> str:
    """The markdown summary of :func:`run`'s rows: one line per model."""
    lines = [
        "| model | assets | fit PSNR min | median | mean | worst asset | s per asset |",
        "|---|---:|---:|---:|---:|---|---:|",
    ]
    for model in dict.fromkeys(r["model"] for r in rows):
        rs = [r for r in rows if r["model"] == model]
        psnr = [r["fit_psnr_db"] for r in rs]
        worst = min(rs, key=lambda r: r["fit_psnr_db"])
        lines.append(
            f"| {model} | {len(rs)} | {min(psnr):.2f} | {statistics.median(psnr):.2f} | {statistics.fmean(psnr):.2f} "
            f"| {worst['object']} / {worst['light']} | {statistics.fmean(r['seconds'] for r in rs):.1f} |"
        )
    return "\n".join(lines) + "\n"


def run(args: argparse.Namespace) -> int:
    from frng.apps.asset import AssetRenderer
    from frng.apps.export import bake
    from frng.render import envmap

    try:
        jobs = assets(args.results, args.models, args.objects, max(1, args.lights))
    except FileNotFoundError as e:
        print(f"frng bench export: error: {e}", file=sys.stderr)
        return 2
    args.out.mkdir(parents=True, exist_ok=True)
    rows = []
    with open(args.out / "export.csv", "w", newline="") as f:  # a row per asset as it is measured
        w = csv.DictWriter(f, COLUMNS)
        w.writeheader()
        for i, (model, obj, light, folder, map_path) in enumerate(jobs):
            t0 = time.perf_counter()
            baked = bake(AssetRenderer(folder), envmap.read(map_path), args.exposure, light={"map": str(map_path)})
            row = {
                "model": model, "object": obj, "light": light, "gaussians": len(baked),
                "fit_psnr_db": round(baked.fit_psnr_db, 3), "seconds": round(time.perf_counter() - t0, 1),
            }  # fmt: skip
            rows.append(row)
            w.writerow(row)
            f.flush()
            print(f"[{i + 1}/{len(jobs)}] {model} {obj} {light}: {row['gaussians']} Gaussians, "
                  f"fit {row['fit_psnr_db']:.2f} dB ({row['seconds']:.0f} s)", flush=True)  # fmt: skip
    table = summary(rows)
    (args.out / "summary.md").write_text(
        f"# frng bench export: SH fit of {args.results}'s assets ({args.exposure:+g} EV)\n\n{table}"
    )
    print(table, end="")
    below = [r for r in rows if args.floor is not None and r["fit_psnr_db"] < args.floor]
    for r in below:
        print(f"below the floor {args.floor} dB: {r['model']} {r['object']} {r['light']} {r['fit_psnr_db']:.2f} dB")
    return 1 if below else 0
