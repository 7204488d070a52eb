"""``frng config PATH [OVERLAY ...]``: validate a config file (with overlays merged over it in order, as Snakemake's
``--configfile PATH OVERLAY ...`` merges them) and print it with the schema's defaults filled in (``--json``;
``--check``: print nothing when it is valid). Run by make before snakemake; no rule runs it.

``frng config --write-docs`` (``make config-docs``) writes config/schema.yaml and config/README.md's key tables from
the keys the section dataclasses declare (:mod:`frng.plan.schema_gen`)."""

from __future__ import annotations

import argparse
import json

from frng.plan.config import ConfigError, dump, load_overlaid


def configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("path", nargs="?", help="config YAML to validate")
    parser.add_argument(
        "overlays",
        nargs="*",
        metavar="OVERLAY",
        help="config YAMLs merged over PATH in order (make seeds: config/seeds.yaml)",
    )
    parser.add_argument("--json", action="store_true", help="print the filled-in config as JSON")
    parser.add_argument("--check", action="store_true", help="validate only: print nothing when the config is valid")
    parser.add_argument(
        "--write-docs",
        action="store_true",
        help="write config/schema.yaml and config/README.md's key tables from the declared keys (no PATH)",
    )


def write_docs() -> int:
    from frng.plan import schema_gen
    from frng.typedconfig import Config

    for path in schema_gen.write(Config):
        print(f"wrote {path.relative_to(schema_gen.ROOT)}")
    return 0


def run(args: argparse.Namespace) -> int:
    if args.write_docs:
        return write_docs()
    if args.path is None:
        print("frng config: PATH is required (or --write-docs)")
        return 2
    try:
        config = load_overlaid(args.path, *args.overlays)
    except ConfigError as e:
        named = " + ".join([args.path, *args.overlays])
        where = "" if str(e).startswith("config file") else f"{named}: "  # file-level errors name it already
        print(f"invalid config: {where}{e}")
        return 1
    if not args.check:
        print(json.dumps(config, indent=2) if args.json else dump(config))
    return 0
