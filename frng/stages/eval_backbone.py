"""Stage ``frng eval-backbone`` (rule ``eval_backbone``): quality of the frozen priors on held-out (test) objects,
beside trivial baselines -> ``{results}/metrics/backbone.csv`` and ``idm.csv``; prints a summary (means per
task/method).

What is measured and the CSV columns: :mod:`frng.priors.evaluate`.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from frng.device import resolve_device
from frng.plan import catalog
from frng.plan import config as frng_config
from frng.plan.layout import Layout
from frng.priors import build_idm, load_backbone
from frng.priors.evaluate import eval_backbone, eval_idm, mean_image
from frng.typedconfig import typed

# The config keys this stage reads (frng.plan.digests: its rule's digest): both splits, build_idm, seeds, device; the
# backbone model from its file (frng/priors/evaluate.py)
CONFIG_READS = ("@plan", "device", "idm", "!idm.train", "backbone.near", "backbone.far")


def configure(parser: argparse.ArgumentParser) -> None:
    frng_config.add_config_argument(parser)
    parser.add_argument("--model", help="backbone model (default {results}/backbone/model.pt)")
    parser.add_argument("--backbone-csv", help="default {results}/metrics/backbone.csv")
    parser.add_argument("--idm-csv", help="default {results}/metrics/idm.csv")


def run(args: argparse.Namespace) -> int:
    import pandas as pd

    from frng import io
    from frng.priors.dataset import load_split

    config = typed(frng_config.load(args.config))
    L = Layout(config.results)
    device = resolve_device(config.device)
    plan = catalog.plan(config)
    train_objs = load_split(config.results, plan.split("train"))
    test = load_split(config.results, plan.split("test"))
    model = load_backbone(Path(args.model or L.backbone_model()), device)
    bb = pd.DataFrame(eval_backbone(config.seed, model, test, mean_image(train_objs), device))
    idm = pd.DataFrame(eval_idm(build_idm(config.idm, config.backbone, config.results, device), test, train_objs))
    for df, path in ((bb, args.backbone_csv or L.metrics("backbone")), (idm, args.idm_csv or L.metrics("idm"))):
        with io.atomic_path(path) as tmp:
            df.to_csv(tmp, index=False, float_format="%.5g")
    print(bb.groupby(["task", "method"])[["psnr", "ssim"]].mean().round(3).to_string())
    print(
        idm.groupby("method")[["normal_deg", "albedo_psnr", "roughness_mae", "metallic_mae", "depth_mae"]]
        .mean()
        .round(3)
        .to_string()
    )
    return 0
