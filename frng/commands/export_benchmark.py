"""Stage ``frng export --layout LAYOUT --object OBJ --out DIR`` (no rule: run by hand and by the tests): a curated
object written in a public benchmark's published layout (file names, encodings, camera and map conventions as
shipped), so the importers can be tested on real files: export -> ``frng import`` round-trips
(``tests/test_benchmarks.py``). Prints the path ``frng import LAYOUT`` takes. ``--out`` is built in a staging folder and
swapped in (:func:`frng.confine.staged_output`, exports add up); a non-empty folder that is not a previous export is
refused unless ``--force``."""

from __future__ import annotations

import argparse

from frng.plan import config as frng_config
from frng.typedconfig import typed


def configure(parser: argparse.ArgumentParser) -> None:
    from frng.benchmarks import LAYOUTS

    frng_config.add_config_argument(parser)
    parser.add_argument("--layout", required=True, choices=list(LAYOUTS), help="the published layout to write")
    parser.add_argument("--object", required=True, help="curated object id")
    parser.add_argument("--out", required=True, help="output folder")
    parser.add_argument("--scene", help="scene name in the layout (default: the object id)")
    parser.add_argument(
        "--force",
        action="store_true",
        help="write into a non-empty --out that is not a previous export (files of the same names are replaced; "
        "others kept)",
    )


def run(args: argparse.Namespace) -> int:
    from pathlib import Path

    from frng import cli, confine
    from frng.benchmarks import BenchmarkError, export_object
    from frng.data.dataset import DatasetError

    config = typed(frng_config.load(args.config))
    try:
        if args.scene is not None:
            confine.plain_name(args.scene, source="--scene", field="")
        # built in a staging folder and swapped in: a failure leaves --out as it was; exports add up (merge)
        with confine.staged_output(args.out, "export", args.force, merge=True) as stage:
            staged = export_object(args.layout, config.results, args.object, stage, args.scene)
        path = Path(args.out) / Path(staged).relative_to(stage)
    except (BenchmarkError, DatasetError, confine.UntrustedInputError) as e:
        if cli.DEBUG:  # `frng --debug`: the traceback
            raise
        print(f"frng export: error: {e}")
        return 2
    print(path)
    return 0
