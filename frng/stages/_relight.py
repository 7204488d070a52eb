"""What the three relighting stages share (:mod:`.relight`, :mod:`.relight_seed`, :mod:`.relight_benchmark`): the
arguments and the run of ``frng relight``; not a stage itself (each rule runs the stage named after it, with its
own ``CONFIG_READS``)."""

from __future__ import annotations

import argparse
import json

from frng.apps.relight import ALL_GROUPS, BACKBONE, RelightError, RelightJob, relight
from frng.plan import config as frng_config
from frng.typedconfig import typed


def configure(parser: argparse.ArgumentParser) -> None:
    frng_config.add_config_argument(parser)
    parser.add_argument("--object", required=True, help="test object id")
    parser.add_argument("--models", help="folder of trained variants (default {results}/models)")
    parser.add_argument("--device", help="override the config's device")
    parser.add_argument(
        "--group",
        default=ALL_GROUPS,
        help="relight only the runs of this group: 'main' (the models' seed runs and the backbone, writes the timing) "
        "or a training seed of train.seeds other than the models' (its {variant}@s{seed} runs); default 'all'",
    )


def run(args: argparse.Namespace) -> int:
    config = typed(frng_config.load(args.config))
    try:
        timing = relight(RelightJob.of(config), args.object, args.models, args.device, args.group)
    except RelightError as e:
        print(f"frng relight: error: {e}")
        return 2
    if "speedup" not in timing:
        print(
            f"relight {args.object}: group {args.group} done (no timing: the full run and the backbone are in 'main')"
        )
        return 0
    f, b = timing["F-RNG"], timing[BACKBONE]
    print(
        f"relight {args.object}: F-RNG {f['relight_ms_per_image']:.1f} ms/image, backbone "
        f"{b['relight_ms_per_image']:.1f} ms/image ({timing['speedup']:.1f}x) at {timing['resolution']} px, "
        f"F-RNG reconstruction {f['reconstruction_s']:.2f} s"
    )
    print(json.dumps(timing, indent=1))
    return 0
