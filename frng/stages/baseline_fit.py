"""Stage ``frng baseline-fit --object OBJ --method METHOD --views N --out DIR`` (rule ``baseline_fit``, one job
per baseline object, method and view count): one per-scene baseline fitted on N of the object's dense views, its
novel views and (a method that relights: gsir) relit images written to the RelightFolder DIR. Methods:
:mod:`frng.baselines.registry`. What the job reads and writes:
:mod:`frng.baselines.fit_job`.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from frng.baselines import registry
from frng.baselines.fit_job import BaselineFitError, FitJob, fit_object
from frng.plan import config as frng_config
from frng.typedconfig import typed

# The config keys this stage reads (frng.plan.digests: its rule's digest): the object's views and lights (plan), the
# fit's budget and schedule, the rasterizer and shading, seeds, device (frng/baselines/perscene.py)
CONFIG_READS = ("@plan", "train_seed", "device", "render", "!render.noise_floor", "baselines.fit", "raster", "shading")


def configure(parser: argparse.ArgumentParser) -> None:
    frng_config.add_config_argument(parser)
    parser.add_argument("--object", required=True, help="test object id (with {results}/baselines/views/{obj})")
    parser.add_argument("--method", required=True, choices=list(registry.names()), help="per-scene baseline")
    parser.add_argument("--views", required=True, type=int, help="dense views fitted on (the nested spread subset)")
    parser.add_argument("--out", required=True, help="output RelightFolder ({results}/relight/{method}-v{N}/{obj})")
    parser.add_argument("--device", help="override the config's device")


def run(args: argparse.Namespace) -> int:
    config = typed(frng_config.load(args.config))
    try:
        rec = fit_object(FitJob.of(config), args.object, args.method, int(args.views), Path(args.out), args.device)
    except BaselineFitError as e:
        print(f"frng baseline-fit: error: {e}", file=sys.stderr)
        return 2
    print(
        f"baseline-fit {rec['run']} {args.object}: {rec['fit_seconds']:.1f} s fit ({rec['steps']} steps, "
        f"{rec['gaussians']} Gaussians), train PSNR {rec['train_psnr']:.2f} dB, loss {rec['first_loss']:.4f} -> "
        f"{rec['final_loss']:.4f}"
    )
    return 0
