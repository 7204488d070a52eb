"""Stage ``frng baseline-eval [--out DIR]`` (rule ``baseline_eval``): every baseline run (per-scene ``3dgs-v{n}`` /
``gsir-v{n}``, the image-based ``idm-reshade``, other methods' folders ``baselines.external``) and F-RNG's ``full``
and ``full-nvs`` runs scored per image against the ground truth under the config's ``eval.protocol`` (the protocol of
``frng evaluate``; :mod:`frng.baselines.scoring`). Writes ``{results}/metrics/baselines_per_image.csv`` and
``baselines_timing.csv``.

Config keys read: ``results``, ``eval.protocol``, ``eval.background``, ``render.dense_views``, ``baselines.*``
(objects_per_class, view_counts, methods, image_based, external) and the dataset plan (the test split, each test
object's planned material class)."""

from __future__ import annotations

import argparse

from frng.baselines.plan import FRNG_NVS_RUN
from frng.plan import config as frng_config
from frng.typedconfig import typed

# The config keys this stage reads (frng.plan.digests: its rule's digest): the runs planned (dense views,
# baselines.*), the protocol (frng/baselines/scoring.py)
CONFIG_READS = ("@plan", "eval", "render.dense_views", "baselines", "benchmarks")


def configure(parser: argparse.ArgumentParser) -> None:
    frng_config.add_config_argument(parser)
    parser.add_argument("--out", help="metrics folder (default {results}/metrics)")
    parser.add_argument(
        "--no-frng-nvs", action="store_true", help="do not score F-RNG's novel views (run full-nvs) in the views table"
    )


def run(args: argparse.Namespace) -> int:
    from pathlib import Path

    from frng import metrics as M
    from frng.baselines.external import ExternalError
    from frng.baselines.scoring import ScoringError, score
    from frng.plan.layout import Layout

    config = typed(frng_config.load(args.config))
    out = Path(args.out or Layout(config.results).metrics_dir())
    from frng.baselines.scoring import planned

    runs = planned(config)
    if args.no_frng_nvs:
        runs = [r for r in runs if r.run != FRNG_NVS_RUN]
    try:
        per_image, timing = score(config.results, runs, config.eval.protocol, config.eval.background, out)
    except (ScoringError, ExternalError) as e:
        print(f"frng baseline-eval: error: {e}")
        return 2
    df = M.read_csv(per_image)
    print(f"baseline-eval ({config.eval.protocol} protocol): wrote {per_image} and {timing}")
    print(df.groupby(["task", "run"], sort=False)[["psnr", "ssim", "lpips"]].mean().to_string())
    return 0
