"""Stage ``frng import LAYOUT PATH`` (rule ``import_benchmark``, one job per ``benchmarks:`` entry): a public
benchmark scene into the dataset contract, ``{results}/objects/{id}/`` (+ its lights in ``{results}/envmaps/``),
so that relighting and evaluation read it unchanged.

Layouts and what each reads: :mod:`frng.benchmarks` (one module per benchmark, citing its official loader); the
conversion (rig-like input views, targets, masks, cameras, world normalisation, resampling to
``render.resolution``): :mod:`frng.benchmarks.common`. Bad input is one line naming the file (exit 2), and nothing
is left that looks imported.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from frng.plan import config as frng_config
from frng.plan.layout import Layout
from frng.typedconfig import typed

# The config keys this stage reads (frng.plan.digests: its rule's digest): the import converts to the resolution, map
# width and input-view count (frng/benchmarks)
CONFIG_READS = ("benchmarks", "render.resolution", "render.extra_input_views", "envmaps.width")


def configure(parser: argparse.ArgumentParser) -> None:
    from frng.benchmarks import LAYOUTS

    parser.add_argument("layout", choices=list(LAYOUTS), help="the benchmark's published layout")
    parser.add_argument(
        "path",
        help="tensoir: the scene folder (train_*/, test_*/); orb: blender_HDR/{scene}; "
        "owl: dataset/{object}/test; nerf-synthetic: the scene folder",
    )
    frng_config.add_config_argument(parser)
    parser.add_argument("--id", help="object id (default {layout}-{scene}; must contain a hyphen)")
    parser.add_argument("--results", help="results folder to import into (default: the config's)")
    parser.add_argument("--max-targets", type=int, help="keep the first N test views")
    parser.add_argument("--envmaps", help="tensoir: folder of {light}.hdr (default ../light_probes)")
    parser.add_argument("--input-light", help="tensoir: the training light (default: the one found, else sunset)")
    parser.add_argument("--lights", nargs="*", help="tensoir: the target lights (default: all found)")
    parser.add_argument("--ground-truth", help="orb: the ground_truth/ folder (default ../../ground_truth)")
    parser.add_argument(
        "--envmap",
        dest="envmap_file",
        help="nerf-synthetic: the light (default ../envmaps/{scene}.exr, else constant white)",
    )
    parser.add_argument(
        "--allow-outside",
        action="store_true",
        help="read files the scene's files name outside the scene folder (absolute or ../ paths, symlinks out); "
        "refused by default (docs/reliability.md)",
    )


OPTIONS = {
    "tensoir": ("envmaps", "input_light", "lights"),
    "orb": ("ground_truth",),
    "owl": (),
    "nerf-synthetic": ("envmap_file",),
}


def run(args: argparse.Namespace) -> int:
    from frng import cli
    from frng.benchmarks import BenchmarkError, import_scene
    from frng.confine import UntrustedInputError, check_id

    config = typed(frng_config.load(args.config))
    opts = {k: getattr(args, k) for k in OPTIONS[args.layout]}
    opts["allow_outside"] = bool(getattr(args, "allow_outside", False))
    if args.id is not None:
        try:
            check_id(args.id)
        except UntrustedInputError as e:
            if cli.DEBUG:  # `frng --debug`: the traceback
                raise
            print(f"frng import: error: {e}")
            return 2
    if args.id and "-" not in args.id:
        print(
            f"frng import: error: --id {args.id!r} must contain a hyphen (imported ids are kept apart from "
            f"curated ones)"
        )
        return 2
    try:
        folder = import_scene(
            args.layout,
            args.path,
            args.results or config.results,
            config.render.resolution,
            config.envmaps.width,
            config.render.extra_input_views,
            args.max_targets,
            args.id,
            **opts,
        )
    except BenchmarkError as e:
        if cli.DEBUG:  # `frng --debug`: the traceback
            raise
        print(f"frng import: error: {e}")
        return 2
    meta = Layout(args.results or config.results).object_meta(Path(folder).name)
    print(f"import {args.layout} {args.path}: wrote {folder} ({meta})")
    return 0
