"""Stage ``frng evaluate`` (rule ``evaluate``): per-image relighting metrics of every run of every test object
(:mod:`frng.apps.scoring`: what is scored, the protocol, the CSVs)."""

from __future__ import annotations

import argparse
from pathlib import Path

from frng import metrics as M
from frng.apps.scoring import CROSS_LIGHT, evaluate, run_dirs_of
from frng.plan import config as frng_config
from frng.plan.layout import Layout
from frng.typedconfig import typed

# The config keys this stage reads (frng.plan.digests: its rule's digest): eval.protocol/background and the planned
# runs (frng/plan/variants.py: the variants, the training seeds, whether the Lambertian-base run exists)
CONFIG_READS = (
    "eval",
    "frng",
    "idm.kind",
    "render.extra_input_views",
    "train.seeds",
    "train_seed",
    "seed",
    "shading.decoder_cosine",
)


def configure(parser: argparse.ArgumentParser) -> None:
    frng_config.add_config_argument(parser)
    frng_config.add_test_objects_argument(parser)
    parser.add_argument("--out", help="metrics folder (default {results}/metrics)")


def run(args: argparse.Namespace) -> int:

    config = typed(frng_config.load(args.config))
    objects = frng_config.heldout_objects(config, args.objects)
    out = Path(args.out or Layout(config.results).metrics_dir())
    per_image, summary = evaluate(config.results, config.eval, run_dirs_of(config, objects), out)
    print(f"evaluate ({config.eval.protocol} protocol): wrote {per_image}, {summary} and {out / CROSS_LIGHT}")
    print(M.read_csv(summary).to_string(index=False))
    return 0
