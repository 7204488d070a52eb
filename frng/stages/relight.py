"""Stage ``frng relight --object OBJ [--group G]`` (rules ``relight`` and ``relight_seed``, one job per test object
and relighting group): relight one held-out object with every F-RNG run and with the backbone, timed side by side,
or with the runs of one group only (``main``: the models' seed and the backbone; a training seed: its
``{variant}@s{seed}`` runs); prints the timing.

What one job does, the runs, the outputs and the timing file: :mod:`frng.relight`.
"""

from __future__ import annotations

import argparse
import json

from frng.plan import config as frng_config
from frng.relight import ALL_GROUPS, BACKBONE, RelightError, RelightJob, relight
from frng.typedconfig import typed

# The config keys this stage reads (frng.plan.digests: its rule's digest): the dataset plan (the split check) and what
# relighting reads (frng/relight.py, group @relight). The rule `relight` relights the main group only
# (frng.plan.variants.MAIN_GROUP: the models' seed and the backbone), whose runs do not depend on the other training
# seeds: it leaves train.seeds out, so that `make seeds` (train.seeds [0] -> [0, 1]) adds the relight_seed jobs
# without rerunning the first seed's relight jobs (their outputs were identical)
CONFIG_READS = ("@plan", "@relight", "!train.seeds")


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
