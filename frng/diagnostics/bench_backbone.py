"""``frng bench backbone``: how well trained backbones relight the held-out split, and how much they follow the
target light, under inference settings the pipeline does not vary -- the loop for experiments on the baseline
(train a backbone with ``frng backbone-train --out``, or change how it is run, and score it here beside the
pipeline's), without relighting folders or the ``relight`` rule.

Per test object (``--split val``: the validation objects of ``frng bench heldout``, which the backbone trained on,
target views included; or ``--objects``) and model:

1. reconstructs the object from its rig's input views under its first input light, as the ``relight`` stage does
   (:meth:`frng.priors.backbone.RelitLRMBackbone.reconstruct`, told the input light);
2. relights it under every target light with the stage's DDIM seeds (:meth:`~frng.priors.backbone.RelitLRMBackbone.
   relight_one`), so that the default setting's scores equal the pipeline's backbone rows image by image
   (``tests/test_smoke_workflow.py``);
3. scores each image under the config's ``eval`` protocol and against the next test light's ground truth: the light
   sensitivity, PSNR with the right light minus PSNR with another (the ladder's s-rows).

A model is ``NAME=PATH`` with optional inference settings after commas (``--model g2=results/backbone/model.pt,
guidance=2,normals=gbuffer,head=zero``): the denoiser's guidance scale, where the light cue reads its normals, and
whether the per-pixel head's learned output is kept (:mod:`frng.priors.backbone_settings`).

The report is ``frng bench heldout``'s (:func:`frng.diagnostics._heldout.summary`): per model PSNR / SSIM / LPIPS, the
light sensitivity, PSNR per material class, target-view elevation and target light, and every model after the first
against the first with paired 95% bootstrap intervals over objects. ``--out`` writes the per-image rows (CSV)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from frng.diagnostics._heldout import SCORES, add_bench_arguments, named_path, selected_objects, summary
from frng.plan import config as frng_config

if TYPE_CHECKING:  # torch is imported when a benchmark runs, not by `frng bench --help`
    from frng.priors.backbone_settings import BackboneSettings


def _model_arg(text: str) -> tuple[str, Path, BackboneSettings]:
    from frng.priors.backbone_settings import BackboneSettings

    name, rest = named_path(text, "backbone=results/backbone/model.pt,guidance=2")
    path, *pairs = rest.split(",")
    settings = {}
    for pair in pairs:
        key, eq, value = pair.partition("=")
        if not eq:
            raise argparse.ArgumentTypeError(f"--model {text!r}: setting {pair!r} is not key=value")
        settings[key] = value
    try:
        return name, Path(path), BackboneSettings.parse(settings)
    except ValueError as e:
        raise argparse.ArgumentTypeError(f"--model {text!r}: {e}") from None


def configure(parser: argparse.ArgumentParser) -> None:
    add_bench_arguments(
        parser,
        _model_arg,
        "NAME=PATH[,key=value...]",
        "a trained backbone model.pt under a name, with optional settings guidance=G, normals=hull|gbuffer|depth, "
        "head=learned|zero (see the module doc); repeat to compare (the first is the reference). Default: "
        "backbone={results}/backbone/model.pt",
        "test: the config's test split (default); val: every fifth object of the sorted training split (the "
        "backbone trained on them, their target views included: how well it fits, not how it generalises)",
    )


def relit(obj, backbone, settings: BackboneSettings, seed: int, device) -> dict:
    """One backbone's renders of one :class:`frng.priors.dataset.PriorObject` (targets loaded) at its target views
    under each target light, run as ``settings`` asks: {light: linear premultiplied RGBA (Vt, H, W, 4) numpy}, with
    the relight stage's DDIM seeds (``catalog.derive_seed(seed, "relight", oid, light)``)."""
    import torch

    from frng.plan import catalog

    light_in = obj.input_lights[0]
    v = obj.inputs[light_in].select(range(obj.rig_views))  # the relight stage's main run: the rig
    rgb, a, c2w, intr = (x.to(device) for x in (v.rgb, v.alpha, v.c2w, v.intr))
    H, W = rgb.shape[1:3]
    env_in = obj.envs[light_in].to(device)
    gb_normals = obj.gbuffer.normal[: len(v)].to(device) if obj.gbuffer is not None else None
    nd = backbone.cfg.den_views
    out = {}
    with torch.no_grad():
        recon = backbone.reconstruct(rgb, a, c2w, intr)
        try:
            recon = settings.reconstruction(backbone, recon, rgb, a, c2w, env_in, gb_normals)
        except ValueError as e:
            raise ValueError(f"{obj.id}: {e}") from None
        for light, tv in obj.targets.items():
            g = torch.Generator(device=device).manual_seed(catalog.derive_seed(seed, "relight", obj.id, light))
            env = obj.envs[light].to(device)
            t_c2w, t_intr = tv.c2w.to(device), tv.intr.to(device)
            rgba = backbone.relight_one(
                recon, env, c2w[:nd], intr[:nd], t_c2w, t_intr, H, W, generator=g, guidance=settings.guidance
            )
            out[light] = rgba.float().cpu().numpy()
    return out


def score_object(obj, backbones: dict, seed: int, protocol: str, background, device) -> list:
    """Per-image rows of one test object for each of ``backbones`` (name -> (loaded backbone, its
    :class:`BackboneSettings`)): ``model``, ``decoder`` ("full"), ``light``, ``view``, psnr / ssim / lpips and
    ``psnr_other_light`` (NaN with one target light)."""
    from frng import metrics as M
    from frng.metrics import other_light

    lights = obj.target_lights
    names = obj.targets[lights[0]].names
    gts = {}
    for light, tv in obj.targets.items():
        if tv.names != names:
            raise ValueError(f"{obj.id}: the target lights' views differ ({light})")
        gts[light] = np.concatenate([tv.rgb.numpy(), tv.alpha.numpy()], -1)
    rows = []
    for name, (backbone, settings) in backbones.items():
        for light, pred in relit(obj, backbone, settings, seed, device).items():
            wrong = other_light(lights, light)
            for k, view in enumerate(names):
                m = M.evaluate_pair(pred[k], gts[light][k], protocol=protocol, background=background)
                cross = M.psnr_pair(pred[k], gts[wrong][k], protocol=protocol, background=background)
                rows.append(
                    {"object": obj.id, "model": name, "decoder": "full", "light": light, "view": view}
                    | {key: m[key] for key in SCORES}
                    | {"psnr_other_light": cross if wrong != light else float("nan")}
                )
    return rows


def run(args: argparse.Namespace) -> int:
    import pandas as pd
    import torch
    from tqdm import tqdm

    from frng.io import read_json
    from frng.plan import catalog
    from frng.plan.layout import Layout
    from frng.priors import load_backbone
    from frng.priors.backbone_settings import BackboneSettings
    from frng.priors.dataset import load_object
    from frng.typedconfig import typed

    if args.threads:
        torch.set_num_threads(args.threads)
    config = typed(frng_config.load(args.config))
    L = Layout(config.results)
    models = args.model or [("backbone", Path(L.backbone_model()), BackboneSettings())]
    plan = catalog.plan(config)
    objects = selected_objects(plan, args, [(name, path) for name, path, _ in models], "backbone")
    if objects is None:
        return 2
    device = torch.device("cpu")
    backbones = {}
    for name, path, settings in models:  # one load per model: the settings change it in place
        try:
            backbones[name] = (settings.apply(load_backbone(path, device)), settings)
        except ValueError as e:
            print(f"frng bench backbone: error: model {name}: {e}", file=sys.stderr)
            return 2
    described = "; ".join(f"{name}: {settings.describe()}" for name, _, settings in models)
    print(
        f"# frng bench backbone: {len(objects)} objects{'' if args.objects else f' ({args.split})'}, protocol "
        f"{config.eval.protocol}, threads {torch.get_num_threads()}; {described}",
        flush=True,
    )
    gbuffer = any(settings.normals == "gbuffer" for _, _, settings in models)
    rows = []
    for oid in tqdm(objects, desc="backbone", file=sys.stderr):
        obj = load_object(config.results, oid, with_targets=True, with_gbuffer=gbuffer)
        if not obj.targets:
            print(f"frng bench backbone: error: {oid}: no target views", file=sys.stderr)
            return 2
        meta = read_json(L.object_meta(oid))
        elevation = {c["name"]: c["elevation_deg"] for c in meta["views"]["targets"]}
        try:
            scored = score_object(obj, backbones, config.seed, config.eval.protocol, config.eval.background, device)
        except ValueError as e:
            print(f"frng bench backbone: error: {e}", file=sys.stderr)
            return 2
        for r in scored:
            extra = {
                "class": meta["material_class"],
                "elevation_deg": elevation[r["view"]],
                "light_base": plan.envmap(r["light"]).base,
            }
            rows.append(r | extra)
    df = pd.DataFrame(rows)
    if args.out:
        Path(args.out).parent.mkdir(parents=True, exist_ok=True)
        df.to_csv(args.out, index=False)
    print(summary(df, [name for name, _, _ in models]))
    return 0 if np.isfinite(df["psnr"]).all() else 1
