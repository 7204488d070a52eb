"""Stage ``frng curate-baselines --object OBJ`` (rule ``curate_baselines``, one job per test object): ONE Blender
process renders the object's target views under its first input light and, for the per-scene baselines' objects,
its dense views (:mod:`frng.baselines.curate`). Torch-free, like ``frng curate``."""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from frng import io
from frng.baselines.curate import curate_baselines
from frng.baselines.plan import baseline_objects, test_objects
from frng.data.curate import CurationError
from frng.data.stopguard import StopGuard
from frng.plan import catalog, dataset_config
from frng.plan import config as frng_config
from frng.plan.layout import Layout
from frng.plan.sections import config_section
from frng.render import envmap

# The config keys this stage reads (frng.plan.digests: its rule's digest): the object's curation settings (render.*,
# envmaps.width), the plan (its lights, split, material; which test objects get dense views:
# baselines.objects_per_class); frng/baselines/curate.py
CONFIG_READS = ("@plan", "render", "!render.noise_floor", "envmaps.width", "baselines.objects_per_class")


def configure(parser: argparse.ArgumentParser) -> None:
    frng_config.add_config_argument(parser)
    parser.add_argument("--object", required=True, help="test object id from the dataset plan")
    parser.add_argument("--envmaps", help="prepared env-map folder (default: {results}/envmaps)")
    parser.add_argument("--meta", help="the object's curated meta.json (default: {results}/objects/OBJ/meta.json)")
    parser.add_argument("--out", help="folder of the baselines' views (default: {results}/baselines/views)")


def run(args: argparse.Namespace) -> int:
    config = frng_config.load(args.config)
    L = Layout(config["results"])
    out = Path(args.out or Path(L.baseline_views_dir(args.object)).parent)
    t0 = time.perf_counter()
    import bpy  # noqa: F401  (before the guard: the import installs Blender's SIGINT handler)

    guard = StopGuard(f"frng curate-baselines {args.object}").install()
    try:
        plan = catalog.plan(config)
        dense = args.object in baseline_objects(config, test_objects(plan))
        final = curate_baselines(
            plan,
            config_section(config, "objects").objaverse,
            config_section(config, "render"),
            config_section(config, "envmaps"),
            args.object,
            Path(args.meta or L.object_meta(args.object)),
            Path(args.envmaps or L.envmaps_dir()),
            out,
            dense,
            log=lambda m: print(m, flush=True),
            guard=guard,
        )
    except (CurationError, dataset_config.CatalogError, envmap.EnvMapError, io.ImageError) as e:
        print(f"frng curate-baselines: error: {e}", file=sys.stderr, flush=True)
        return 1
    print(f"[{args.object}] done: {final} in {time.perf_counter() - t0:.1f} s", flush=True)
    return 0
