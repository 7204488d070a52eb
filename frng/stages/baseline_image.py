"""Stage ``frng baseline-image --object OBJ [--out DIR] [--gbuffer idm|oracle]`` (rule ``baseline_image``, one job
per test object): the image-based relighting baseline ``idm-reshade`` -- each target view's own image under the input
light decomposed by the IDM and re-shaded under every target light (:mod:`frng.baselines.image_based`). Writes the
run folder ``{results}/relight/idm-reshade/{obj}`` (or ``--out``): ``{light}/{view}.exr`` and ``run.json``.

Config keys read: ``results``, ``seed``, ``device``, ``shading.*`` (spp_infer, sampling, alpha_eps, chunk_pixels,
chunk_pairs), ``idm.*`` (kind and, for ``learned``, the model file ``{results}/idm/model.pt``), ``backbone.near`` /
``far`` (the IDM registry's signature)."""

from __future__ import annotations

import argparse

from frng.plan import config as frng_config
from frng.typedconfig import typed

# The config keys this stage reads (frng.plan.digests: its rule's digest): the IDM (registry: idm.*, backbone.near/far),
# the shading, seeds, device (frng/baselines/image_based.py)
CONFIG_READS = ("@plan", "train_seed", "device", "idm", "backbone.near", "backbone.far", "shading")


def configure(parser: argparse.ArgumentParser) -> None:
    from frng.baselines.image_based import GBUFFERS

    frng_config.add_config_argument(parser)
    parser.add_argument("--object", required=True, help="test object id")
    parser.add_argument("--out", help="run folder to write (default {results}/relight/idm-reshade/{obj})")
    parser.add_argument("--device", help="override the config's device")
    parser.add_argument(
        "--gbuffer",
        choices=GBUFFERS,
        default="idm",
        help="idm: the configured IDM on the single image; oracle: the curated ground-truth G-buffer of the target "
        "view (the family's upper bound at this shading model)",
    )


def run(args: argparse.Namespace) -> int:
    from pathlib import Path

    from frng.baselines.image_based import ImageBaselineError, ImageJob, reshade_object
    from frng.baselines.plan import IMAGE_BASED_RUN
    from frng.data.dataset import DatasetError
    from frng.plan.layout import Layout

    config = typed(frng_config.load(args.config))
    out = Path(args.out or Layout(config.results).relight_run(IMAGE_BASED_RUN, args.object))
    try:
        info = reshade_object(ImageJob.of(config), args.object, out, args.gbuffer, args.device)
    except (ImageBaselineError, DatasetError, FileNotFoundError) as e:
        print(f"frng baseline-image: error: {e}")
        return 2
    print(
        f"baseline-image {args.object}: {len(info['target_views'])} view(s) x {len(info['lights'])} light(s) -> {out} "
        f"({info['relight_ms_per_image']:.1f} ms/image, G-buffer: {info['gbuffer']})"
    )
    return 0
