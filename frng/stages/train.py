"""Stage ``frng train --variant V`` (rule ``train``, one job per variant; under torchrun/srun one process per
rank): train one F-RNG variant on the training split from the frozen priors' caches.

The loss, the step and the outputs (``model.pt``, ``checkpoint.pt``, ``loss.csv/png``, ``train.json``):
:mod:`frng.training.frng_trainer`; the loop: :func:`frng.training.loop.fit`; ranks: :mod:`frng.training.distributed`.
"""

from __future__ import annotations

import argparse
import dataclasses
from pathlib import Path

from frng.io import check_file_index
from frng.plan import catalog
from frng.plan import config as frng_config
from frng.plan.layout import Layout
from frng.plan.variants import (
    GEOMETRIES,
    all_variants,
    canonical_variant,
    reads_priors,
    split_seed,
    trained_variants,
)
from frng.training import distributed
from frng.training.frng_trainer import ModelSections, TrainRun, train, variant_config
from frng.typedconfig import typed

# The config keys this stage reads (frng.plan.digests: its rule's digest): train.* (but the seeds: a variant's seed is
# its name's), the architecture (frng.* but the variant lists), decoder and training shading (not the
# inference-only spp_infer / bf16_infer: relight takes those from the config), rasterizer, idm.kind (which priors
# file), the training split, the models' seed, device (frng/training/frng_trainer.py + variant_config)
CONFIG_READS = (
    "@plan",
    "train_seed",
    "device",
    "train",
    "!train.seeds",
    "frng",
    "!frng.variants",
    "!frng.k_sweep",
    "model.patch_size",
    "shading",
    "!shading.spp_infer",
    "!shading.bf16_infer",
    "raster",
    "idm.kind",
)


def configure(parser: argparse.ArgumentParser) -> None:
    frng_config.add_config_argument(parser)
    parser.add_argument(
        "--variant",
        default="full",
        help="full (the paper's F-RNG), its ablations no-fine, no-idm, no-ind, no-neural, k<percent> (the K sweep), "
        "plus (F-RNG+: the config's additions on) or plus-no-<addition> (F-RNG+ without one); --list-variants names "
        "the config's",
    )
    parser.add_argument("--out", help="output folder (default {results}/models/{variant})")
    parser.add_argument("--backbone", help="frozen backbone file (default {results}/backbone/model.pt)")
    parser.add_argument("--steps", type=int, help="override train.steps / train.ablation_steps")
    parser.add_argument("--list-variants", action="store_true", help="print the config's variants and exit")
    parser.add_argument(
        "--geometry",
        choices=GEOMETRIES,
        default="backbone",
        help="what the coarse Gaussians sit on: the backbone's (default) or, diagnostics, the input pixels' surface "
        "distances from their G-buffers (gbuffer: F-RNG's geometry gap, docs/model-and-training.md), their visual "
        "hull (hull) or the hull refined by multi-view stereo (stereo, frng/priors/stereo.py); needs --out",
    )


def run(args: argparse.Namespace) -> int:
    config = typed(frng_config.load(args.config))
    if args.list_variants:
        for v in all_variants(config):
            c = canonical_variant(config, v)
            print(v if c == v else f"{v} (= {c})")
        return 0
    if args.variant not in all_variants(config) and canonical_variant(config, args.variant) not in trained_variants(
        config
    ):
        variant_config(
            ModelSections.of(config), args.variant
        )  # raises for unknown names; other k<percent> values are allowed
    if args.geometry != "backbone" and not args.out:
        raise ValueError(f"--geometry {args.geometry} needs --out (a diagnostic model is not the pipeline's)")
    layout = Layout(config.results)
    out = Path(args.out or layout.model_dir(args.variant))
    # the training split's files as the indexes recorded them (rules training_set_*): a truncated or corrupted
    # cache is named here rather than deep in the loader
    priors = reads_priors(canonical_variant(config, split_seed(args.variant)[0]))
    indexes = [layout.backbone_cache_index()] + ([layout.idm_priors_index()] if priors else [])
    for index in indexes:
        if Path(index).exists():
            check_file_index(index)
    # {variant}@s{seed} (train.seeds): the variant trained with train_seed = seed (frng.plan.variants.split_seed)
    base, seed = split_seed(args.variant)
    if seed is not None:
        config = dataclasses.replace(config, train_seed=seed)
    job = TrainRun(
        results=config.results,
        seed=config.model_seed,
        device=config.device,
        idm_kind=config.idm.kind,
        train_ids=tuple(catalog.plan(config).split("train")),
    )
    path = train(
        ModelSections.of(config), config.train, job, base, out, args.backbone, steps=args.steps, geometry=args.geometry
    )
    print(f"train: wrote {path}")
    distributed.cleanup()
    return 0
