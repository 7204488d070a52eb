"""Stage ``frng curate --object OBJ`` (rule ``curate``, one job per object): ONE Blender process renders ONE
object's views x lights and G-buffers.

The work, the outputs and how a failed or stopped job cleans up: :mod:`frng.data.curate`.

Torch-free: the stage builds only the config sections curation reads (:func:`frng.plan.sections.config_section`), not
the whole typed config (:mod:`frng.typedconfig` imports every model), and the numpy halves of :mod:`frng.render.envmap`
and :mod:`frng.camera` leave torch unimported (:mod:`frng.lazytorch`): ~2.5 s of each of the ~140 jobs of a
default-tier run (tests/test_lazy_imports.py).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from frng import io
from frng.data.curate import CurationError, curate
from frng.data.stopguard import StopGuard
from frng.plan import catalog, dataset_config
from frng.plan import config as frng_config
from frng.plan.layout import Layout
from frng.plan.sections import config_section
from frng.render import envmap

# The config keys this stage reads (frng.plan.digests: its rule's digest): render.* (rig, Cycles, fur) and envmaps.width
# (frng/data/curate.py), and envmaps.normalize (the maps' scale); the object's own plan entry (its split, mesh,
# material, seed and lights) and its maps' plan records are its record file (rule curate_record, an input named by
# their digest; the env-map index is an ancient input: rules/curate.smk), so adding an object reruns no other
# curation. objects.objaverse is read too, but only where the
# GLB cache is and whether to fetch a missing uid (cache, download): the mesh of a uid is the same file wherever
# it is cached, and the uids, filter and material reach the spec
CONFIG_READS = ("render", "!render.dense_views", "!render.noise_floor", "envmaps.width", "envmaps.normalize")


def configure(parser: argparse.ArgumentParser) -> None:
    frng_config.add_config_argument(parser)
    parser.add_argument("--object", required=True, help="object id from the dataset plan (obj_0000, user_<stem>, ...)")
    parser.add_argument("--envmaps", help="prepared env-map folder (default: {results}/envmaps)")
    parser.add_argument("--out", help="objects folder (default: {results}/objects)")


def run(args: argparse.Namespace) -> int:
    config = frng_config.load(args.config)  # validated; the sections are built below, torch-free
    L = Layout(config["results"])
    env_dir = Path(args.envmaps or L.envmaps_dir())
    out = Path(args.out or L.objects_dir())
    t0 = time.perf_counter()
    import bpy  # noqa: F401  (before the guard: the import installs Blender's SIGINT handler)

    guard = StopGuard(f"frng curate {args.object}").install()
    try:
        final = curate(
            catalog.plan(config),
            config_section(config, "objects").objaverse,
            config_section(config, "render"),
            config_section(config, "envmaps"),
            args.object,
            env_dir,
            out,
            log=lambda m: print(m, flush=True),
            guard=guard,
        )
    except (CurationError, dataset_config.CatalogError, envmap.EnvMapError, io.ImageError) as e:
        print(f"frng curate: error: {e}", file=sys.stderr, flush=True)
        return 1
    print(f"[{args.object}] done: {final} in {time.perf_counter() - t0:.1f} s", flush=True)
    return 0
