"""Stage ``frng envmaps`` (rule ``envmaps``): prepare every environment map of the dataset plan.

The work, outputs and all-or-nothing writing: :mod:`frng.data.envmaps`.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from frng import io
from frng.data.envmaps import prepare
from frng.plan import catalog, dataset_config
from frng.plan import config as frng_config
from frng.plan.layout import Layout
from frng.render import envmap
from frng.typedconfig import typed

# The config keys this stage reads (frng.plan.digests: its rule's digest): the env-map plan, envmaps.width/normalize,
# Blender threads of the sky bakes (frng/data/envmaps.py)
CONFIG_READS = ("@envmap_plan", "render.threads")


def configure(parser: argparse.ArgumentParser) -> None:
    frng_config.add_config_argument(parser)
    parser.add_argument("--out", help="output folder (default: {results}/envmaps)")


def run(args: argparse.Namespace) -> int:
    config = typed(frng_config.load(args.config))
    out = Path(args.out) if args.out else Path(Layout(config.results).envmaps_dir())
    from frng.data.stopguard import StopGuard

    try:
        import bpy  # noqa: F401  (before the guard: the import installs Blender's SIGINT handler)
    except ImportError:
        pass  # users' maps need no Blender; load_base says so otherwise
    guard = StopGuard("frng envmaps").install()
    t0 = time.perf_counter()
    try:
        specs = catalog.envmap_plan(config)
        records = prepare(
            config.envmaps, specs, config.render.threads, out, log=lambda m: print(m, flush=True), guard=guard
        )
    except (envmap.EnvMapError, dataset_config.CatalogError, io.ImageError) as e:
        print(f"frng envmaps: error: {e}", file=sys.stderr)
        return 1
    n_test = sum(r["split"] == "test" for r in records)
    print(
        f"[envmaps] wrote {len(records)} maps ({len(records) - n_test} train, {n_test} test) to {out} "
        f"in {time.perf_counter() - t0:.1f} s",
        flush=True,
    )
    return 0
