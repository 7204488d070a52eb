"""``frng bench heldout``: how good trained F-RNG models are on the held-out split, in about a minute per model on
two CPU cores -- the loop for experiments on the model (train a variant with ``frng train --out``, score it here
beside the full model), without relighting folders, the 13-model ``relight`` rule or ``evaluate``.

What it does per test object (``catalog.plan(config).split("test")``; ``--split val``: every fifth training object,
:func:`validation_objects`, for choices that must not look at the test objects; or ``--objects``) and model:

1. reads the object's CACHED backbone tokens and IDM priors (``{results}/backbone/cache``, ``{results}/idm/priors``,
   what the pipeline's cache rules wrote for the test split; :func:`frng.training.frng_trainer.load_objects`, the training
   loader) instead of running the backbone and the IDM live as ``frng relight`` does (the test split's caches are
   the same tensors: same DDIM seeds);
2. reconstructs from ``--views`` input views, rasterizes the target views once and shades them under every target
   light with the relighting seeds of ``frng relight`` (so a model's scores equal the pipeline's scores of its
   ``full`` run, image by image: ``tests/test_smoke_workflow.py``), and the Lambertian base alone
   (:func:`frng.apps.relight.shade_base`, the ladder's "Lambertian base only" row) where the decoder has one;
3. scores each image under the config's ``eval`` protocol (:func:`frng.metrics.evaluate_pair`), and the light
   sensitivity: PSNR with the right light minus PSNR against the next test light's ground truth
   (:func:`frng.metrics.other_light`, the ladder's s-rows).

Prints, per model: PSNR / SSIM / LPIPS, the base's PSNR, the light sensitivity, the PSNR per material class and
per band of the target view's elevation (views from below see what the rig's cameras, at 0 and 45 degrees, never
do) and per target light (the map's base name: a test studio or sky over its rotations); and every model after
the first against the first: the paired difference with its 95% bootstrap interval over objects
(:func:`frng.report.stats.paired`). Models named ``NAME@sS`` are training seeds of ``NAME`` (the pipeline's
naming, :func:`seed_groups`): they are compared as one model, averaged over its seeds, with the interval resampling
the seeds too (the two-level bootstrap of :mod:`frng.report.stats`, as the pipeline's ``vs_backbone`` and
``ablation`` tables). ``--out`` writes the per-image rows (CSV).

``--at inputs`` scores the models at their own V INPUT views instead (:func:`score_inputs`): re-rendered under the
input light (the reconstruction) and under every other input light the object was photographed in (relighting
where the geometry is exact by construction: each input pixel has its own Gaussian). Beside the target-view
scores this splits a model's error into what the representation loses where it was seen and what novel views add.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from frng.diagnostics._heldout import (
    AT,
    _model_arg,
    add_bench_arguments,
    score_inputs,
    score_object,
    selected_objects,
    summary,
)
from frng.plan import config as frng_config
from frng.plan.variants import GEOMETRIES, RIG_VIEWS


def configure(parser: argparse.ArgumentParser) -> None:
    add_bench_arguments(
        parser,
        _model_arg,
        "NAME=PATH",
        "a trained F-RNG model.pt under a name; repeat to compare (the first is the reference). Names "
        "NAME@sS are training seeds of NAME (e.g. full=... full@s1=...): their scores are averaged and the "
        "comparisons resample the seeds as well as the objects. Default: full={results}/models/full/model.pt",
        "test: the config's test split (default); val: every fifth object of the sorted training split, to "
        "choose between variants without looking at the test objects (the models trained on them; their caches "
        f"hold the rig's {RIG_VIEWS} views only)",
    )
    parser.add_argument(
        "--views", type=int, default=RIG_VIEWS, help=f"input views (default {RIG_VIEWS}; cached counts)"
    )
    parser.add_argument(
        "--at",
        choices=AT,
        default=AT[0],
        help="score at the target views under the target lights (default), or re-render the model's own input "
        "views under the input light and the object's other input lights",
    )
    parser.add_argument(
        "--geometry",
        choices=GEOMETRIES,
        default="backbone",
        help="what every model's coarse Gaussians sit on: the backbone's (default) or, diagnostics, the input "
        "pixels' surface distances from their G-buffers, their visual hull or the hull refined by multi-view stereo "
        "(gbuffer / hull / stereo; with a model `frng train --geometry ...` trained the same way: F-RNG's geometry "
        "gap, docs/model-and-training.md)",
    )


def run(args: argparse.Namespace) -> int:
    import pandas as pd
    import torch
    from tqdm import tqdm

    from frng.io import read_json
    from frng.model.composed import FRNG
    from frng.plan import catalog
    from frng.plan.layout import Layout, TrainingFolder
    from frng.priors import build_idm
    from frng.training.frng_trainer import load_objects
    from frng.typedconfig import typed

    if args.threads:
        torch.set_num_threads(args.threads)
    config = typed(frng_config.load(args.config))
    L = Layout(config.results)
    given = args.model or [("full", Path(TrainingFolder(Path(L.models_dir()) / "full").model()))]
    plan = catalog.plan(config)
    objects = selected_objects(plan, args, given, "heldout")
    if objects is None:
        return 2
    models = dict(given)
    dev = torch.device("cpu")
    loaded = {n: FRNG.load(p, dev).set_inference_shading(config.shading) for n, p in models.items()}
    uses_priors = any(m.cfg.uses_priors for m in loaded.values())
    spp = int(config.shading.spp_infer)
    idm = build_idm(config.idm, config.backbone, config.results, dev) if uses_priors else None
    print(
        f"# frng bench heldout: {len(objects)} objects"
        f"{'' if args.objects else f' ({args.split})'}, {args.views} views, at the {args.at[:-1]} views, "
        f"protocol {config.eval.protocol}, "
        f"threads {torch.get_num_threads()}",
        flush=True,
    )
    rows = []
    proto, bg = config.eval.protocol, config.eval.background
    for oid in tqdm(objects, desc="heldout", file=sys.stderr):
        try:
            (obj,) = load_objects(
                config.results,
                config.idm.kind,
                [oid],
                L.backbone_model(),
                uses_priors,
                args.views,
                idm=idm,
                geometry=args.geometry,
            )
        except KeyError as e:  # a cache without that view count (training objects hold the rig's only)
            print(f"frng bench heldout: error: {oid}: {e.args[0]}", file=sys.stderr)
            return 2
        meta = read_json(L.object_meta(oid))
        if args.at == "inputs":
            for r in score_inputs(obj, loaded, config.results, config.seed, spp, proto, bg):
                rows.append(r | {"class": meta["material_class"]})
            continue
        lights = list(meta["target_lights"])
        views = [c["name"] for c in meta["views"]["targets"]]
        elevation = {c["name"]: c["elevation_deg"] for c in meta["views"]["targets"]}
        base = {light: plan.envmap(light).base for light in lights}
        for r in score_object(obj, loaded, lights, views, config.seed, spp, proto, bg):
            extra = {
                "class": meta["material_class"],
                "elevation_deg": elevation[r["view"]],
                "light_base": base[r["light"]],
            }
            rows.append(r | extra)
    df = pd.DataFrame(rows)
    if args.out:
        Path(args.out).parent.mkdir(parents=True, exist_ok=True)
        df.to_csv(args.out, index=False)
    print(summary(df, list(models)))
    return 0 if np.isfinite(df["psnr"]).all() else 1
