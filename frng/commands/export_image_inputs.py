"""Stage ``frng export-image-inputs --out DIR [--objects ...]`` (no rule: run by hand, before running an image-based
method elsewhere): per test object and target view, the photo under the input light (sRGB PNG + linear EXR), its
mask, the camera, and each target environment map in the world frame and rotated into the camera frame as Neural
Gaffer expects (:mod:`frng.baselines.export_inputs`; docs/baselines.md). Needs the rule ``curate_baselines``'s views.

Config keys read: ``results`` and the dataset plan (the test split: the default objects)."""

from __future__ import annotations

import argparse

from frng.plan import config as frng_config
from frng.typedconfig import typed


def configure(parser: argparse.ArgumentParser) -> None:
    frng_config.add_config_argument(parser)
    parser.add_argument("--out", required=True, help="output folder")
    frng_config.add_test_objects_argument(parser)


def run(args: argparse.Namespace) -> int:
    from frng.baselines.export_inputs import ExportError, export

    config = typed(frng_config.load(args.config))
    objects = frng_config.heldout_objects(config, args.objects)
    try:
        index = export(config.results, objects, args.out)
    except ExportError as e:
        print(f"frng export-image-inputs: error: {e}")
        return 2
    print(index)
    return 0
