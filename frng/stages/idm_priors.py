"""Stage ``frng idm-priors --object OBJ [OBJ ...]`` (rules ``idm_priors_{batch}``, one job per batch of objects,
:mod:`frng.plan.batches`): each object's IDM priors for all its input views in its own file (schema:
:mod:`frng.priors.cache`), one after another in this process."""

from __future__ import annotations

import argparse
import time
from pathlib import Path

from frng.device import resolve_device
from frng.plan import config as frng_config
from frng.plan.batches import add_batch_arguments, object_outputs
from frng.plan.layout import Layout
from frng.priors.cache import make_idm_priors
from frng.typedconfig import typed

# The config keys this stage reads (frng.plan.digests: its rule's digest): the learned IDM from its file; idm.kind and
# the diffusion-renderer settings (frng/priors/cache.py + build_idm), near/far, device
CONFIG_READS = ("device", "idm", "!idm.train", "backbone.near", "backbone.far")


def configure(parser: argparse.ArgumentParser) -> None:
    frng_config.add_config_argument(parser)
    add_batch_arguments(parser, "make priors for", "priors", "{results}/priors/idm/{obj}.safetensors")
    parser.add_argument("--kind", help="override idm.kind")


def run(args: argparse.Namespace) -> int:
    config = typed(frng_config.load(args.config))
    outs = object_outputs(args.object, args.out, Layout(config.results).idm_priors)
    device = resolve_device(config.device)
    for obj, out in zip(args.object, outs):
        t0 = time.perf_counter()
        path = make_idm_priors(config.idm, config.backbone, config.results, obj, Path(out), device, args.kind)
        print(f"idm-priors: wrote {path} ({time.perf_counter() - t0:.2f} s)", flush=True)
    return 0
