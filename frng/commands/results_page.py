"""Stage ``frng results-page``: ``docs/results.md`` and the README's results block from a results folder's tables,
figures and provenance (:mod:`frng.report.results_page`). The rule ``tables`` does the same through ``frng tables
--results-page PAGE --readme README`` for the default tier; this subcommand is for doing it by hand, e.g. for an
earlier run whose commit, date, minutes or machine the folder does not record (``--commit`` ...).

Writes only ``--page``, its figures folder (``--figures``) and the block between the README's markers."""

from __future__ import annotations

import argparse
import sys

from frng.report.results_page import ResultsPageError, write_pages


def configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--results", required=True, help="the results folder (its tables/, figures/, config.yaml, logs/)"
    )
    parser.add_argument(
        "--results-page", required=True, metavar="PAGE", help="the page to write (the repository's docs/results.md)"
    )
    parser.add_argument("--readme", help="README whose results block (between its two markers) is rewritten")
    parser.add_argument(
        "--figures", help="where the page's figures are copied (default {PAGE's folder}/figures/results)"
    )
    parser.add_argument("--repo", help="the checkout whose commit is recorded (default: the page's folder)")
    parser.add_argument("--commit", help="state this commit instead of the checkout's (an earlier run)")
    parser.add_argument("--date", help="state this date (YYYY-MM-DD) instead of the newest table's")
    parser.add_argument("--minutes", type=float, help="state these minutes instead of the logs' span")
    parser.add_argument("--machine", help="state this machine instead of this one's CPU")


def run(args: argparse.Namespace) -> int:
    overrides = {k: getattr(args, k) for k in ("commit", "date", "minutes", "machine") if getattr(args, k) is not None}
    try:
        out = write_pages(args.results, args.results_page, args.readme, args.figures, args.repo, overrides)
    except ResultsPageError as e:  # names the file
        print(f"frng results-page: error: {e}", file=sys.stderr)
        return 2
    print(out.summary())
    return 0
