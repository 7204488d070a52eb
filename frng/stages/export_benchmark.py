"""Stage ``frng export --layout LAYOUT --object OBJ --out DIR`` (no rule: run by hand and by the tests): a curated
object written in a public benchmark's published layout (file names, encodings, camera and map conventions as
shipped), so the importers can be tested on real files: export -> ``frng import`` round-trips
(``tests/test_benchmarks.py``). Prints the path ``frng import LAYOUT`` takes."""

from __future__ import annotations

import argparse

from frng import config as frng_config
from frng.typedconfig import typed


def configure(parser: argparse.ArgumentParser) -> None:
    from frng.benchmarks import LAYOUTS

    frng_config.add_config_argument(parser)
    parser.add_argument("--layout", required=True, choices=list(LAYOUTS), help="the published layout to write")
    parser.add_argument("--object", required=True, help="curated object id")
    parser.add_argument("--out", required=True, help="output folder")
    parser.add_argument("--scene", help="scene name in the layout (default: the object id)")


def run(args: argparse.Namespace) -> int:
    from frng.benchmarks import BenchmarkError, export_object
    from frng.data.dataset import DatasetError

    config = typed(frng_config.load(args.config))
    try:
        path = export_object(args.layout, config.results, args.object, args.out, args.scene)
    except (BenchmarkError, DatasetError) as e:
        print(f"frng export: error: {e}")
        return 2
    print(path)
    return 0
