"""``frng bench targets-noise``: the curated images' Monte-Carlo noise floor, and what denoising, more samples or
Cycles' clamps buy (:mod:`frng.data.noise_floor`).

Renders target views of planned objects exactly as curation does (the object's own target lights or ``--lights``)
under the settings of ``--settings`` and scores each against a high-spp reference of the same view
(the mean of two raw unclamped renders of ``--reference-spp`` samples, default 512, with other seeds), aligned protocol by default. Setting
``tier`` is the config's ``render.*`` (the dataset's images): its row is the targets' noise floor. Specs
``SPP[+oidn[=P]][+noclamp|+clamp=D/I]`` (:func:`frng.data.noise_floor.parse_setting`).

Writes into ``--out``: ``renders.csv`` (one row per object, light, view and setting: metrics and render seconds),
``summary.md`` (per setting: mean / min PSNR, SSIM, LPIPS, seconds per view and per object at the config's
renders per object; PSNR per material and per light) and, with ``--save-images``, every render as
``images/{obj}/{light}/{view}/{setting}.exr``. Times at ``render.threads`` (``--threads``).
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import time
from pathlib import Path

from frng.data import noise_floor as N
from frng.plan import config as frng_config
from frng.plan.layout import Layout


def configure(parser: argparse.ArgumentParser) -> None:
    frng_config.add_config_argument(parser)
    parser.add_argument(
        "--objects", nargs="+", help="object ids of the plan (default: the first test object of each material)"
    )
    parser.add_argument("--lights", nargs="+", help="maps of the env-map folder (default: each object's target lights)")
    parser.add_argument("--views", type=int, default=2, help="target views per object and light (the rig's first)")
    parser.add_argument("--resolution", type=int, help="image size in px (default: render.resolution)")
    parser.add_argument("--threads", type=int, help="Cycles threads (default: render.threads)")
    parser.add_argument(
        "--reference-spp", type=int, default=512, help="samples of each of the reference's two renders (raw, no clamps)"
    )
    parser.add_argument(
        "--settings", nargs="+", default=[N.TIER], help="tier | SPP[+oidn[=P]][+noclamp|+clamp=D/I] (module docstring)"
    )
    parser.add_argument("--protocol", default="aligned", help="metric protocol (frng.metrics)")
    parser.add_argument("--envmaps", help="prepared env-map folder (default: {results}/envmaps)")
    parser.add_argument("--out", required=True, help="folder for renders.csv, summary.md (and images/)")
    parser.add_argument("--save-images", action="store_true", help="write every render as EXR under --out/images")


def run(args: argparse.Namespace) -> int:
    from frng.plan.sections import config_section

    config = frng_config.load(args.config)
    render = config_section(config, "render")
    try:
        settings = [N.parse_setting(s, render) for s in args.settings]
    except ValueError as e:
        print(f"frng bench targets-noise: error: {e}", file=sys.stderr)
        return 2
    if len({s.name for s in settings}) != len(settings) or {N.REFERENCE, N.HALF} & {s.name for s in settings}:
        print("frng bench targets-noise: error: --settings names repeat or clash", file=sys.stderr)
        return 2
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    import bpy  # noqa: F401

    from frng.plan import catalog, dataset_config

    plan = catalog.plan(config)
    sized = dataclasses.replace(
        render, resolution=args.resolution or render.resolution, threads=args.threads or render.threads
    )
    try:
        records = N.render_images(
            plan,
            config_section(config, "objects").objaverse,
            sized,
            config_section(config, "envmaps").width,
            Path(args.envmaps or Layout(config["results"]).envmaps_dir()),
            args.objects or N.default_objects(plan),
            args.lights,
            args.views,
            None,
            args.reference_spp,
            settings,
            out,
            args.save_images,
            log=lambda m: print(m, flush=True),
        )
    except (FileNotFoundError, dataset_config.CatalogError) as e:
        print(f"frng bench targets-noise: error: {e}", file=sys.stderr)
        return 1
    rows = N.score(records, args.protocol)
    import pandas as pd

    pd.DataFrame(rows).to_csv(out / "renders.csv", index=False)
    same_size = args.resolution in (None, render.resolution)
    text = N.summary(rows, sized, N.renders_per_object(sized) if same_size else None)
    (out / "summary.md").write_text(text)
    print(text, flush=True)
    print(f"frng bench targets-noise: {len(records)} renders in {time.perf_counter() - t0:.1f} s -> {out}")
    return 0
