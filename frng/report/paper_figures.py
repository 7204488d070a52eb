"""The paper-style figures from the relit images, drawn with :mod:`frng.report.figures` (stage
:mod:`frng.stages.figures`, ``frng figures``).

Outputs (``{results}/figures/``):

- ``comparison/{obj}.png`` per test object: input views | light | ground truth | backbone | F-RNG, one row per
  target light (first target view), PSNR (the configured protocol) captioned on the predictions;
- ``ablation.png``: ground truth and every ablation variant (``frng.variants``), one row per test object (first
  target light and view);
- ``real_objects.png``: the same for the test objects that are real assets (:meth:`frng.plan.catalog.Catalog.real_assets`:
  LIBERO's, Objaverse's, users' files), when there are any: the README's picture;
- ``saliency/{obj}.png`` per test object: input view 0 | saliency map | the selected top-K patches (full run);
- ``loss_curves.png``: the training curves of every run (``{results}/models/*/loss.csv``, the backbone and the
  IDM when present).
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import pandas as pd

from frng import io
from frng.plan.layout import Layout
from frng.plan.variants import BACKBONE, PLUS, full_and
from frng.render import envmap
from frng.report import figures


def _psnr_lookup(per_image: pd.DataFrame):
    key = per_image.set_index(["object", "run", "light", "view"])["psnr"]
    return lambda obj, run, light, view: float(key.get((obj, run, light, view), np.nan))


def comparison(results: Path, oid: str, out_png: Path, psnr) -> None:
    """Per test object: input views, env map, ground truth, backbone, F-RNG (and F-RNG+ where it was relit) under
    each target light; every method told no input light."""
    L = Layout(results)
    full = io.read_json(L.relight_record("full", oid))
    view = full["target_views"][0]
    lights = full["lights"]
    meta = io.read_json(L.object_meta(oid))
    light_in = meta["input_lights"][0]
    inputs = [io.read_rgba(L.object_image(oid, "inputs", light_in, v)) for v in full["input_views"]]
    gt = [io.read_rgba(L.object_image(oid, "targets", l, view)) for l in lights]
    bb = [io.read_rgba(L.relight_image(BACKBONE, oid, l, view)) for l in lights]
    fr = [io.read_rgba(L.relight_image("full", oid, l, view)) for l in lights]
    envs = [envmap.read(L.envmap(l)) for l in lights]
    has_plus = Path(L.relight_record(PLUS, oid)).exists()
    plus = [io.read_rgba(L.relight_image(PLUS, oid, l, view)) for l in lights] if has_plus else None
    figures.object_comparison(
        out_png,
        inputs,
        gt,
        bb,
        fr,
        lights,
        envmaps=envs,
        psnr_backbone=[psnr(oid, BACKBONE, l, view) for l in lights],
        psnr_frng=[psnr(oid, "full", l, view) for l in lights],
        title=f"{oid} ({meta['material_class']}), view {view}",
        plus=plus,
        psnr_plus=[psnr(oid, PLUS, l, view) for l in lights] if has_plus else None,
    )


def ablation(results: Path, objects: list[str], variants: list[str], out_png: Path, psnr, title: str) -> None:
    """Ground truth and each ablation variant, one row per object of ``objects`` (first target light and view)."""
    L = Layout(results)
    gts, imgs, caps, labels = [], {v: [] for v in variants}, {v: [] for v in variants}, []
    for oid in objects:
        info = io.read_json(L.relight_record("full", oid))
        light, view = info["lights"][0], info["target_views"][0]
        gts.append(io.read_rgba(L.object_image(oid, "targets", light, view)))
        for v in variants:
            imgs[v].append(io.read_rgba(L.relight_image(v, oid, light, view)))
            caps[v].append(psnr(oid, v, light, view))
        labels.append(f"{oid} / {light}")
    figures.ablation_grid(out_png, imgs, gts, labels, caps, title=title)


def saliency(results: Path, oid: str, out_png: Path, patch: int) -> None:
    """Input view 0, its saliency map and the selected top-K patches of the full run."""
    d = np.load(Layout(results).relight_saliency("full", oid))
    image, sal, idx = d["image"][0], d["saliency"][0], d["patch_idx"][0]
    H, W = image.shape[:2]
    sel = np.zeros((H // patch) * (W // patch), bool)
    sel[idx] = True
    figures.saliency_overlay(
        out_png,
        image,
        sal,
        sel.reshape(H // patch, W // patch),
        patch,
        title=f"{oid}: saliency and top-K patches (view 0)",
    )


def loss_curves(results: Path, out_png: Path) -> None:
    """Every training run's loss.csv: F-RNG variants, backbone, IDM."""
    L = Layout(results)
    runs = {}
    for p in sorted(Path(L.models_dir()).glob(os.path.relpath(L.model_curve("*"), L.models_dir()))):
        runs[f"F-RNG {p.parent.name}"] = pd.read_csv(p)
    for name, p in (("backbone", Path(L.backbone_curve())), ("idm", Path(L.idm_curve()))):
        if p.exists():
            runs[name] = pd.read_csv(p)
    if not runs:
        raise FileNotFoundError(f"no training curves: {results}/models/*/loss.csv, backbone/ or idm/loss.csv")
    figures.loss_curves(runs, out_png, title="Training losses (all runs)")


def make_figures(
    results: str | Path,
    patch_size: int,
    variants: Sequence[str],
    objects: list[str],
    out_dir: Path,
    real_objects: Sequence[str] = (),
) -> list[Path]:
    """The paper's figures of ``objects`` into ``out_dir``: ``patch_size`` is the config's ``model.patch_size`` (the
    saliency maps' patches), ``variants`` its ``frng.variants`` (the ablation figures, after ``full``);
    ``real_objects``: those of ``objects`` that are real assets (``real_objects.png``, written only when there are
    any)."""
    from frng.metrics import read_csv

    results = Path(results)
    psnr = _psnr_lookup(read_csv(Layout(results).metrics("relight_per_image")))
    written = []
    for oid in objects:
        p = out_dir / "comparison" / f"{oid}.png"
        comparison(results, oid, p, psnr)
        s = out_dir / "saliency" / f"{oid}.png"
        saliency(results, oid, s, int(patch_size))
        written += [p, s]
    variants = full_and(variants)
    ablation(results, objects, variants, out_dir / "ablation.png", psnr, "Ablations (PSNR per image)")
    written.append(out_dir / "ablation.png")
    real_set = set(real_objects)
    real = [o for o in objects if o in real_set]
    if real:
        title = "Real objects under held-out lights: ground truth, F-RNG and its ablations (PSNR per image)"
        ablation(results, real, variants, out_dir / "real_objects.png", psnr, title)
        written.append(out_dir / "real_objects.png")
    loss_curves(results, out_dir / "loss_curves.png")
    return written + [out_dir / "loss_curves.png"]
