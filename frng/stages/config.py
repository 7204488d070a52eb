"""``frng config PATH``: validate a config file and print it with the schema's defaults filled in (``--json``;
``--check``: print nothing when it is valid). Run by make before snakemake; no rule runs it."""

from __future__ import annotations

import argparse
import json

from frng.config import ConfigError, dump, load


def configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("path", help="config YAML to validate")
    parser.add_argument("--json", action="store_true", help="print the filled-in config as JSON")
    parser.add_argument("--check", action="store_true", help="validate only: print nothing when the config is valid")


def run(args: argparse.Namespace) -> int:
    try:
        config = load(args.path)
    except ConfigError as e:
        where = "" if str(e).startswith("config file") else f"{args.path}: "  # file-level errors name it already
        print(f"invalid config: {where}{e}")
        return 1
    if not args.check:
        print(json.dumps(config, indent=2) if args.json else dump(config))
    return 0
