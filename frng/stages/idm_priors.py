"""Stage ``frng idm-priors --object OBJ`` (rule ``idm_priors``, one job per object): one object's IDM priors for
all its input views (schema: :mod:`frng.priors.cache`)."""

from __future__ import annotations

import argparse
from pathlib import Path

from frng import config as frng_config
from frng.device import resolve_device
from frng.layout import Layout
from frng.priors.cache import make_idm_priors
from frng.typedconfig import typed


def configure(parser: argparse.ArgumentParser) -> None:
    frng_config.add_config_argument(parser)
    parser.add_argument("--object", required=True)
    parser.add_argument("--kind", help="override idm.kind")
    parser.add_argument("--out", help="priors file (default {results}/priors/idm/{obj}.safetensors)")


def run(args: argparse.Namespace) -> int:
    config = typed(frng_config.load(args.config))
    out = Path(args.out or Layout(config.results).idm_priors(args.object))
    device = resolve_device(config.device)
    print(f"idm-priors: wrote {make_idm_priors(config, args.object, out, device, args.kind)}")
    return 0
