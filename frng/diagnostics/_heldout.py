"""What ``frng bench heldout`` and ``frng bench backbone`` share (:mod:`.bench_heldout`, :mod:`.bench_backbone`):
scoring trained models on held-out objects, the arguments that pick them, the summary; not a stage itself."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from frng.plan import config as frng_config
from frng.plan.variants import split_seed

AT = ("targets", "inputs")  # --at: where the models are scored


SPLITS = ("test", "val")  # --split: the test split, or the validation objects (validation_objects)


VAL_EVERY = 5  # the validation objects: every fifth of the sorted training split


# the per-image columns of frng.metrics.evaluate_pair kept
SCORES = ("psnr", "psnr_interior", "silhouette_iou", "ssim", "lpips")

ELEVATION_BANDS = (-90.0, -30.0, 0.0, 30.0, 90.0)  # degrees; the summary's target-view elevation bands


def named_path(text: str, example: str) -> tuple[str, str]:
    """``--model NAME=REST`` -> (NAME, REST), NAME checked as the pipeline's names are (``NAME@sS``: a training seed
    of NAME, :func:`frng.plan.variants.split_seed`); argparse errors naming the argument (``example``: a valid one)."""
    name, sep, rest = text.partition("=")
    if not sep or not name or not rest:
        raise argparse.ArgumentTypeError(f"--model takes NAME=PATH (e.g. {example}), got {text!r}")
    try:
        split_seed(name)
    except ValueError as e:
        raise argparse.ArgumentTypeError(f"--model {text!r}: {e}") from None
    return name, rest


def _model_arg(text: str) -> tuple[str, Path]:
    name, path = named_path(text, "full=results/models/full/model.pt")
    return name, Path(path)


def seed_groups(names: list[str]) -> dict[str, list[str]]:
    """Model names grouped as training seeds of one model by the pipeline's naming (``x`` and ``x@s1`` are two seeds
    of ``x``; :func:`frng.plan.variants.split_seed`), in the order given: {group: [names]}."""
    groups: dict[str, list[str]] = {}
    for n in names:
        groups.setdefault(split_seed(n)[0], []).append(n)
    return groups


def validation_objects(train: list[str]) -> list[str]:
    """Every :data:`VAL_EVERY`-th object of the sorted training split (25 of the default tier's 122): the
    validation set of the README's scratch studies, for choosing between variants without the test objects."""
    return sorted(train)[::VAL_EVERY]


def add_bench_arguments(
    parser: argparse.ArgumentParser, model_arg, model_metavar: str, model_help: str, split_help: str
):
    """The held-out benchmarks' common arguments: ``--config``, ``--model`` (repeatable, parsed by ``model_arg``),
    ``--objects`` / ``--split`` (what :func:`selected_objects` reads), ``--out`` (the per-image rows' CSV) and
    ``--threads``."""
    frng_config.add_config_argument(parser)
    parser.add_argument("--model", type=model_arg, action="append", metavar=model_metavar, help=model_help)
    parser.add_argument("--objects", nargs="+", metavar="OBJ", help="objects to score (default: the --split's objects)")
    parser.add_argument("--split", choices=SPLITS, default=SPLITS[0], help=split_help)
    parser.add_argument("--out", help="write the per-image rows to this CSV")
    parser.add_argument("--threads", type=int, default=None, help="torch CPU threads (default: torch's)")


def selected_objects(plan, args: argparse.Namespace, models: list[tuple[str, Path]], bench: str) -> list[str] | None:
    """The objects ``--objects`` / ``--split`` select in the dataset plan (:class:`frng.plan.catalog.Catalog`),
    after checking the ``models`` (name, model file) to score: None after printing an error (``frng bench {bench}:
    error: ...``) that names a repeated model name, a missing model file or the objects that are not the config's."""

    def error(text: str) -> None:
        print(f"frng bench {bench}: error: {text}", file=sys.stderr)

    names = [name for name, _ in models]
    if len(set(names)) != len(names):
        return error(f"model names repeat: {names}")
    for name, path in models:
        if not Path(path).exists():
            return error(f"model {name}: {path} does not exist")
    objects = args.objects or (plan.split("test") if args.split == "test" else validation_objects(plan.split("train")))
    unknown = [o for o in objects if o not in plan.object_ids]
    if unknown:
        return error(f"not objects of this config: {unknown}")
    return objects


def relit(obj, model, c2w, intr, envs: dict, seed: int, spp: int) -> dict:
    """One model's renders of one :class:`frng.training.frng_trainer.TrainObject` at cameras c2w (Vt, 4, 4), intr (Vt, 4)
    (rasterized once) under each of ``envs`` (light name -> HDR map), with ``frng relight``'s light-sample seeds:
    {("full", light): (Vt, H, W, 4), and ("base", light): the Lambertian base alone where the decoder has one}."""
    import torch

    from frng.apps.relight import shade_base
    from frng.plan import catalog

    H, W = obj.images.shape[1:3]
    priors = obj.priors if model.cfg.uses_priors else None
    renders = {}
    with torch.no_grad():
        rec = model.reconstruct(obj.views, 0, priors, obj.images)  # the input light estimated, not told
        raster = model.rasterize(rec, c2w, intr, H, W)
        for light, env in envs.items():
            g = torch.Generator().manual_seed(catalog.derive_seed(seed, "relight-frng", obj.id, light))
            renders["full", light] = model.shade(raster, env, spp, generator=g).float().cpu().numpy()
            if model.cfg.head == "neural" and model.decoder.cosine:
                renders["base", light] = shade_base(model, raster, env).float().cpu().numpy()
    return renders


def score_object(
    obj, models: dict, target_lights: list[str], view_names: list[str], seed: int, spp: int, protocol: str, background
) -> list:
    """Per-image rows of one :class:`frng.training.frng_trainer.TrainObject` (test object) under each of ``models`` (name ->
    loaded :class:`frng.model.composed.FRNG`): ``model``, ``decoder`` (``full`` / ``base``), ``light``, ``view``
    (``view_names``: the target views in the order of the object's cameras), psnr/ssim/lpips and
    ``psnr_other_light``."""
    import torch

    from frng import metrics as M
    from frng.metrics import other_light

    targets = {}
    for light, env, c2w, intr, rgba in obj.targets:
        targets.setdefault(light, (env, c2w, intr, rgba))
    missing = [l for l in target_lights if l not in targets]
    if missing:
        raise ValueError(f"{obj.id}: no target images for light(s) {missing}")
    _, c2w, intr, _ = targets[target_lights[0]]
    if any(not torch.equal(targets[l][1], c2w) for l in target_lights):
        raise ValueError(f"{obj.id}: the target lights' cameras differ")
    if c2w.shape[0] != len(view_names):
        raise ValueError(f"{obj.id}: {c2w.shape[0]} target cameras but {len(view_names)} target view names")
    gts = {l: targets[l][3].numpy() for l in target_lights}
    envs = {light: targets[light][0] for light in target_lights}
    rows = []
    for name, model in models.items():
        for (decoder, light), pred in relit(obj, model, c2w, intr, envs, seed, spp).items():
            wrong = other_light(target_lights, light)
            for k in range(pred.shape[0]):
                m = M.evaluate_pair(pred[k], gts[light][k], protocol=protocol, background=background)
                cross = M.psnr_pair(pred[k], gts[wrong][k], protocol=protocol, background=background)
                rows.append(
                    {"object": obj.id, "model": name, "decoder": decoder, "light": light, "view": view_names[k]}
                    | {key: m[key] for key in SCORES}
                    | {"psnr_other_light": cross if wrong != light else float("nan")}
                )
    return rows


def score_inputs(obj, models: dict, results, seed: int, spp: int, protocol: str, background) -> list:
    """Per-image rows of one test object's own V input views (``--at inputs``): each of ``models`` (name -> loaded
    :class:`frng.model.composed.FRNG`) reconstructs from them, rasterizes them once and shades them under the input light
    (``case`` "reconstruction") and every other input light of the object (``case`` "relight"), scored against
    the photographs (the ``decoder`` "base" rows: the Lambertian base alone). Columns as :func:`score_object`'s,
    ``psnr_other_light`` NaN, plus ``case``."""
    from frng import metrics as M
    from frng.data.dataset import open_object

    data = open_object(results, obj.id)
    c2w, intr = obj.views["c2w"].float(), obj.views["intr"].float()
    V = obj.images.shape[0]
    assert c2w.shape == (V, 4, 4) and intr.shape == (V, 4) and len(obj.view_names) == V, (c2w.shape, obj.view_names)
    light_in = data.input_lights[0]
    rows_of = [data.view_names("inputs").index(n) for n in obj.view_names]  # other input lights: all input views
    gts, envs = {light_in: obj.images.numpy()}, {light_in: obj.env_in}
    for light, env, _, _, rgba in obj.targets:  # the object's other input lights, as load_objects read them
        if light in data.input_lights[1:]:
            gts[light], envs[light] = rgba[rows_of].numpy(), env
    rows = []
    for name, model in models.items():
        for (decoder, light), pred in relit(obj, model, c2w, intr, envs, seed, spp).items():
            for k in range(V):
                m = M.evaluate_pair(pred[k], gts[light][k], protocol=protocol, background=background)
                rows.append(
                    {"object": obj.id, "model": name, "decoder": decoder, "light": light, "view": obj.view_names[k]}
                    | {key: m[key] for key in SCORES}
                    | {"psnr_other_light": float("nan"), "case": "reconstruction" if light == light_in else "relight"}
                )
    return rows


def summary(df, names: list[str]) -> str:
    """The printed report of the per-image rows ``df`` (with a ``class`` column) for ``names`` (first = reference)."""
    import pandas as pd

    from frng.report.stats import paired

    full = df[df["decoder"] == "full"]
    lines = []
    table = []
    for name in names:
        d = full[full["model"] == name]
        base = df[(df["model"] == name) & (df["decoder"] == "base")]
        row = {
            "model": name,
            "images": len(d),
            "psnr": d["psnr"].mean(),
            "psnr_interior": d["psnr_interior"].mean() if "psnr_interior" in d else float("nan"),
            "ssim": d["ssim"].mean(),
            "lpips": d["lpips"].mean(),
            "base_psnr": base["psnr"].mean() if len(base) else float("nan"),
            "light_sensitivity": (d["psnr"] - d["psnr_other_light"]).mean(),
        }
        row |= {f"psnr[{c}]": v for c, v in d.groupby("class")["psnr"].mean().items()}
        if "case" in d:  # --at inputs
            row |= {f"psnr[{c}]": v for c, v in d.groupby("case")["psnr"].mean().items()}
        table.append(row)
    lines.append(pd.DataFrame(table).set_index("model").to_string(float_format=lambda x: f"{x:.4f}"))
    if "elevation_deg" in full and full["elevation_deg"].notna().any():
        edges = ELEVATION_BANDS
        labels = [f"{lo:+.0f}..{hi:+.0f}" for lo, hi in zip(edges[:-1], edges[1:])]
        band = pd.cut(full["elevation_deg"], edges, labels=labels, include_lowest=True).rename("elevation")
        by = full.groupby([band, "model"], observed=True)["psnr"].agg(["mean", "count"]).unstack("model")
        lines.append(
            "PSNR by target-view elevation (degrees; mean, images):\n" + by.to_string(float_format="{:.2f}".format)
        )
    if "light_base" in full and full["light_base"].notna().any():
        by = full.groupby(["light_base", "model"])["psnr"].agg(["mean", "count"]).unstack("model")
        lines.append(
            "PSNR by target light (the map's base name, over its rotations; mean, images):\n"
            + by.to_string(float_format="{:.2f}".format)
        )
    groups = seed_groups(names)  # a one-seed group keeps its model's own name
    groups = {g if len(m) > 1 else m[0]: m for g, m in groups.items()}
    frames = {g: [full[full["model"] == n] for n in members] for g, members in groups.items()}
    for g, members in groups.items():
        if len(members) > 1:
            means = ", ".join(f"{n} {f['psnr'].mean():.4f}" for n, f in zip(members, frames[g]))
            spread = np.ptp([f["psnr"].mean() for f in frames[g]])
            lines.append(f"{g}: {len(members)} training seeds, PSNR {means} (spread {spread:.4f})")
    (ref_group, ref), *others = frames.items()
    keys = ("object", "light", "view")
    for g, other in others:
        d = {metric: paired(other, ref, metric, keys=keys) for metric in ("psnr", "ssim", "lpips")}
        parts = [f"{m} {r.diff:+.4f} [{r.lo:+.4f}, {r.hi:+.4f}]" for m, r in d.items()]
        p = d["psnr"]
        over = f"{p.objects} objects" + (
            f" and the training seeds ({len(other)} vs {len(ref)})" if len(other) > 1 or len(ref) > 1 else ""
        )
        lines.append(
            f"{g} - {ref_group}: " + ", ".join(parts) + f" (95% bootstrap over {over}; PSNR better on "
            f"{p.better} of {p.objects})"
        )
    return "\n".join(lines)
