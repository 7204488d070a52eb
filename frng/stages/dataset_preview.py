"""Stage ``frng dataset-preview`` (rule ``dataset_preview``): one PNG contact sheet per curated object. The older
spelling ``frng dataset preview`` runs it too (:data:`frng.cli.ALIASES`).

Sheet layout: :mod:`frng.data.preview`. Output: ``{results}/previews/{obj}.png``.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from frng import io
from frng.data.dataset import DatasetError
from frng.data.preview import write_previews
from frng.plan import catalog
from frng.plan import config as frng_config
from frng.plan.layout import Layout
from frng.typedconfig import typed

# The config keys this stage reads (frng.plan.digests: its rule's digest): the plan's object ids (frng/data/preview.py)
CONFIG_READS = ("@plan",)


def configure(parser: argparse.ArgumentParser) -> None:
    p = parser
    frng_config.add_config_argument(p)
    p.add_argument("--objects", nargs="*", help="object ids (default: every object of the plan)")
    p.add_argument("--out", help="output folder (default: {results}/previews)")
    p.add_argument("--cell", type=int, default=128, help="cell size in pixels")
    p.add_argument("--max-views", type=int, default=10, help="columns per block")
    p.add_argument("--max-lights", type=int, default=6, help="rows per block")


def run(args: argparse.Namespace) -> int:
    config = typed(frng_config.load(args.config))
    objects = args.objects or catalog.plan(config).object_ids
    out = Path(args.out) if args.out else Path(Layout(config.results).previews_dir())
    try:
        write_previews(
            config.results, objects, out, args.cell, args.max_views, args.max_lights, log=lambda m: print(m, flush=True)
        )
    except (DatasetError, io.ImageError) as e:
        print(f"frng dataset-preview: error: {e}", file=sys.stderr)
        return 1
    return 0
