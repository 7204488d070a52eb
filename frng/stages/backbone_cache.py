"""Stage ``frng backbone-cache --object OBJ`` (rule ``backbone_cache``, one job per object): cache one object's
backbone tokens and Gaussians (schema: :mod:`frng.priors.cache`)."""

from __future__ import annotations

import argparse
from pathlib import Path

from frng import config as frng_config
from frng.device import resolve_device
from frng.layout import Layout
from frng.priors.cache import make_backbone_cache
from frng.typedconfig import typed


def configure(parser: argparse.ArgumentParser) -> None:
    frng_config.add_config_argument(parser)
    parser.add_argument("--object", required=True)
    parser.add_argument("--model", help="backbone model file (default {results}/backbone/model.pt)")
    parser.add_argument("--out", help="cache file (default {results}/backbone/cache/{obj}.safetensors)")


def run(args: argparse.Namespace) -> int:
    config = typed(frng_config.load(args.config))
    L = Layout(config.results)
    model = Path(args.model or L.backbone_model())
    out = Path(args.out or L.backbone_cache(args.object))
    device = resolve_device(config.device)
    print(f"backbone-cache: wrote {make_backbone_cache(config, args.object, model, out, device)}")
    return 0
