"""Stage ``frng tables`` (rule ``tables``): the paper's tables from the per-image metrics and the relighting timings
-> ``{results}/tables/{table}.{csv,md,tex}``; prints each table.

Which tables, their rows and columns: :mod:`frng.report.paper_tables`; how they are written:
:mod:`frng.report.tables`.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from frng.plan import config as frng_config
from frng.plan.layout import Layout
from frng.report.paper_tables import write_tables
from frng.report.results_page import ResultsPageError, write_pages
from frng.typedconfig import typed

# The config keys this stage reads (frng.plan.digests: its rule's digest): tier and eval.background in the captions
# (frng/report/paper_tables.py), the plan (the test objects' timings, the lights' families of the per-family tables)
CONFIG_READS = ("tier", "eval", "@plan")


def configure(parser: argparse.ArgumentParser) -> None:
    frng_config.add_config_argument(parser)
    parser.add_argument("--metrics", help="per-image CSV (default {results}/metrics/relight_per_image.csv)")
    parser.add_argument(
        "--timing", nargs="*", help="timing JSONs (default {results}/relight/timing/*.json of the test objects)"
    )
    parser.add_argument("--out", help="tables folder (default {results}/tables)")
    parser.add_argument(
        "--cross-light", help="the light-sensitivity CSV (default {results}/metrics/relight_cross_light.csv)"
    )
    parser.add_argument(
        "--prior-metrics",
        help="the priors' evaluation CSV for the quality ladder (default {results}/metrics/backbone.csv)",
    )
    parser.add_argument(
        "--noise-floor",
        help="the targets' noise floor CSV (frng noise-floor), the quality ladder's step 0 (default: none)",
    )
    parser.add_argument(
        "--results-page",
        metavar="PAGE",
        help="then write this generated results page (docs/results.md) from the tables, figures and provenance "
        "(frng.report.results_page; the rule passes it for the default tier)",
    )
    parser.add_argument("--readme", help="with --results-page: the README whose results block is rewritten")


def run(args: argparse.Namespace) -> int:
    from frng.plan import catalog

    config = typed(frng_config.load(args.config))
    L = Layout(config.results)
    plan = catalog.plan(config)
    timing = args.timing or [L.relight_timing(o) for o in plan.split("test")]
    out = write_tables(
        config.tier,
        config.eval.background,
        Path(args.metrics or L.metrics("relight_per_image")),
        [Path(p) for p in timing],
        Path(args.out or L.tables_dir()),
        Path(args.prior_metrics or L.metrics("backbone")),
        Path(args.cross_light or L.metrics("relight_cross_light")),
        families=plan.light_families(),
        sources=plan.object_sources(),
        noise_csv=Path(args.noise_floor) if args.noise_floor else None,
    )
    for name, paths in out.items():
        print(f"== {name} ({paths['md']})\n{paths['md'].read_text()}")
    if args.results_page:
        try:
            print(write_pages(config.results, args.results_page, args.readme).summary())
        except ResultsPageError as e:  # names the file
            print(f"frng tables: error: {e}", file=sys.stderr)
            return 2
    return 0
