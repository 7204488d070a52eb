"""Stage ``frng render-asset ASSET --env MAP --out DIR`` (no rule: run by hand): arguments and error lines around
:func:`frng.apps.render_asset.render` (cameras, turntable, video, bounds: see that module)."""

from __future__ import annotations

import argparse

from frng.apps import render_asset


def configure(parser: argparse.ArgumentParser) -> None:
    render_asset.add_arguments(parser)


def run(args: argparse.Namespace) -> int:
    from frng import cli
    from frng.apps.asset import AssetError
    from frng.apps.capture import CaptureError

    try:
        info = render_asset.render(args)
    except (CaptureError, AssetError) as e:
        if cli.DEBUG:  # `frng --debug`: the traceback
            raise
        print(f"frng render-asset: error: {e}")
        return 2
    print(
        f"render-asset {args.asset}: {info['views']} views at {info['size'][0]}x{info['size'][1]} on "
        f"{info['device']} -> {args.out}" + (f" ({info['video']})" if info["video"] else "")
    )
    return 0
