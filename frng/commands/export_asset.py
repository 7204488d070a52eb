"""Stage ``frng export-asset ASSET --env MAP [--rotation DEG] [--exposure EV] --format ply|spz|glb --out FILE`` (no
rule: run by hand, and the viewer's Export button): an asset relit under one light and baked into plain 3D Gaussian
splatting (:mod:`frng.apps.export`: the bake, the formats and their conventions)."""

from __future__ import annotations

import argparse

from frng.apps import export


def configure(parser: argparse.ArgumentParser) -> None:
    export.add_arguments(parser)


def run(args: argparse.Namespace) -> int:
    import sys

    from frng import cli
    from frng.apps.asset import AssetError
    from frng.apps.capture import CaptureError

    try:
        info = export.export(args)
    except (export.ExportError, CaptureError, AssetError) as e:
        if cli.DEBUG:  # `frng --debug`: the traceback
            raise
        print(f"frng export-asset: error: {e}", file=sys.stderr)
        return 2
    print(
        f"export-asset {args.asset}: {info['gaussians']} Gaussians baked to {info['format']} -> {info['out']}; "
        f"SH fit PSNR {info['fit_psnr_db']:.1f} dB on held-out directions"
    )
    return 0
