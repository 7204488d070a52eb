"""Stage ``frng backbone-cache --object OBJ [OBJ ...]`` (rules ``backbone_cache_{batch}``, one job per batch of
objects, :mod:`frng.plan.batches`): cache each object's backbone tokens and Gaussians in its own file (schema:
:mod:`frng.priors.cache`), one after another in this process."""

from __future__ import annotations

import argparse
import time
from pathlib import Path

from frng.device import resolve_device
from frng.plan import catalog
from frng.plan import config as frng_config
from frng.plan.batches import add_batch_arguments, object_outputs
from frng.plan.layout import Layout
from frng.priors.cache import make_backbone_cache
from frng.typedconfig import typed

# The config keys this stage reads (frng.plan.digests: its rule's digest): the backbone model from its file; extra
# training lights from the env-map plan, DDIM seeds, device (frng/priors/cache.py)
CONFIG_READS = ("@envmap_plan", "device", "backbone.cache_extra_lights")


def configure(parser: argparse.ArgumentParser) -> None:
    frng_config.add_config_argument(parser)
    add_batch_arguments(parser, "cache", "cache", "{results}/backbone/cache/{obj}.safetensors")
    parser.add_argument("--model", help="backbone model file (default {results}/backbone/model.pt)")


def run(args: argparse.Namespace) -> int:
    config = typed(frng_config.load(args.config))
    L = Layout(config.results)
    model = Path(args.model or L.backbone_model())
    outs = object_outputs(args.object, args.out, L.backbone_cache)
    device = resolve_device(config.device)
    envmaps = catalog.plan(config).envmaps
    extra = config.backbone.cache_extra_lights
    for obj, out in zip(args.object, outs):
        t0 = time.perf_counter()
        path = make_backbone_cache(config.results, config.seed, envmaps, extra, obj, model, Path(out), device)
        print(f"backbone-cache: wrote {path} ({time.perf_counter() - t0:.2f} s)", flush=True)
    return 0
