"""Stage ``frng figures`` (rule ``figures``): the paper-style figures from the relit images ->
``{results}/figures/`` (comparison grids, ablation grids, saliency maps, loss curves).

Which figures and what they show: :mod:`frng.report.paper_figures`; how they are drawn: :mod:`frng.report.figures`.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from frng.plan import config as frng_config
from frng.plan.layout import Layout
from frng.report.paper_figures import make_figures
from frng.typedconfig import typed

# The config keys this stage reads (frng.plan.digests: its rule's digest): patch size (saliency), the ablation variants
# (frng/report/paper_figures.py)
CONFIG_READS = ("model.patch_size", "frng.variants")


def configure(parser: argparse.ArgumentParser) -> None:
    frng_config.add_config_argument(parser)
    frng_config.add_test_objects_argument(parser)
    parser.add_argument("--out", help="figures folder (default {results}/figures)")


def run(args: argparse.Namespace) -> int:

    from frng.plan import catalog

    config = typed(frng_config.load(args.config))
    objects = frng_config.heldout_objects(config, args.objects)
    real = catalog.plan(config).real_assets("test")
    out = Path(args.out or Layout(config.results).figures_dir())
    for p in make_figures(config.results, config.model.patch_size, config.frng.variants, objects, out, real):
        print(f"figures: wrote {p}")
    return 0
