"""Stage ``frng view ASSET [--env MAP ...] [--port N]`` / ``frng view --object OBJ --config C`` (no rule: run by
hand): an interactive relighting viewer in the browser on ``127.0.0.1`` (:mod:`frng.apps.view`, viser), rendering
the asset with its own decoder (:class:`frng.apps.asset.AssetRenderer`) on CUDA when there is one, else the CPU.

Maps: the files given with ``--env`` (EXR/HDR, 2:1), the asset's input light, and the test maps of the tier (the
results folder the asset sits in, or ``--config``'s). ``--object``: a relit test object of ``--config``'s results
folder (its full run's asset; ground truth, F-RNG and backbone side by side at its target views and lights).
Remote machine: ``ssh -L 8080:127.0.0.1:8080 HOST`` then open ``http://127.0.0.1:8080`` locally.
Bad input (a missing or malformed asset, a map that is not 2:1, a port in use): one line, exit status 2.
"""

from __future__ import annotations

import argparse
import signal
import sys
import threading


def configure(parser: argparse.ArgumentParser) -> None:
    from frng.apps.view import DEFAULT_PORT

    parser.add_argument("asset", nargs="?", help="asset folder (asset.json, gaussians.ply, decoder.safetensors)")
    parser.add_argument(
        "--env", nargs="+", action="extend", default=[], metavar="MAP", help="equirect maps (EXR/HDR, 2:1) to add"
    )
    parser.add_argument("--port", type=int, default=DEFAULT_PORT, help="port on 127.0.0.1")
    parser.add_argument("--object", help="a relit test object of --config's results folder, instead of ASSET")
    parser.add_argument("--config", help="pipeline config: its results folder's test maps (and --object)")
    parser.add_argument(
        "--resolution", type=int, help="full-quality frame height (default: the asset's rig / the object's views)"
    )
    parser.add_argument("--spp", type=int, help="light samples at full quality (default: the asset's spp_infer)")
    parser.add_argument("--device", default="auto", help="auto (CUDA when available), cuda or cpu")
    parser.add_argument("--out", default="frng-view", help="folder 'Save frame' writes frame_NNN/ into")
    parser.add_argument(
        "--measure",
        type=int,
        metavar="N",
        help="instead of serving: print the median time of N full- and low-quality frames (16:9) and exit",
    )


def run(args: argparse.Namespace) -> int:
    from frng.apps.asset import AssetError
    from frng.apps.capture import CaptureError
    from frng.apps.view import ViewError, check_port, measure, open_viewer, serve
    from frng.plan.sections import ConfigError

    stop = threading.Event()
    try:
        results = None
        if args.config is not None:
            from frng.plan import config as frng_config
            from frng.typedconfig import typed

            results = typed(frng_config.load(args.config)).results
        viewer = open_viewer(
            args.asset, args.env, args.object, results, args.resolution, args.spp, args.device, args.out
        )
        if args.measure is not None:
            if args.measure < 1:
                raise ViewError(f"--measure {args.measure}: at least 1")
            m = measure(viewer, args.measure)
            for q in ("full", "low"):
                f = m[q]
                print(
                    f"{q}: {f['width']}x{f['height']} px, {f['spp']} spp: {f['ms']:.0f} ms per frame on {m['device']}"
                )
            return 0
        check_port(args.port)  # before anything is started or changed
        previous = signal.signal(signal.SIGTERM, lambda *_: stop.set())
        try:
            serve(viewer, args.port, stop, log=lambda m: print(m, flush=True))
        finally:
            signal.signal(signal.SIGTERM, previous)
    except (ViewError, AssetError, CaptureError, ConfigError, FileNotFoundError) as e:
        print(f"frng view: error: {e}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        pass
    return 0
