"""Stage ``frng evaluate`` (rule ``evaluate``): per-image relighting metrics of every run of every test object.

Reads what ``frng relight`` wrote (``{results}/relight/{run}/{obj}/run.json`` and ``{light}/{view}.exr``) and
the ground truth (``{results}/objects/{obj}/targets/{light}/{view}.exr``), scores every image with
:func:`frng.metrics.evaluate_pair` under the config's ``eval.protocol`` (``aligned``: per-channel least-squares
scale, foreground PSNR/SSIM; ``plain``: whole image, no scaling) and ``eval.background``, and writes

- ``{results}/metrics/relight_per_image.csv``: one row per image, columns ``dataset`` (the object's material
  class: diffuse / specular / fur), ``object, run, method, variant, views, k, light, view, psnr, ssim, lpips,
  protocol``, the protocol's ``scale_r/g/b``, the ratio of means ``brightness_r/g/b`` and ``fg_fraction``;
- ``{results}/metrics/relight_summary.csv``: means per ``run`` (plus ``n``), via :func:`frng.metrics.aggregate`,
  ``scale_log2`` (:func:`frng.metrics.scale_log2`: how much colour repair the aligned protocol did per run) and
  ``brightness_log2`` (:func:`frng.metrics.brightness_log2`: how far off the brightness is, by the ratio of means).

Every table (``frng tables``) is recomputed from the per-image CSV.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from frng import config as frng_config
from frng.config import Config
from frng import io
from frng import metrics as M
from frng.layout import Layout, RelightFolder

PER_IMAGE = "relight_per_image.csv"
SUMMARY = "relight_summary.csv"
COLUMNS = ("dataset", "object", "run", "method", "variant", "views", "k", "light", "view", "psnr", "ssim", "lpips",
           "protocol")


def evaluate_run(results: Path, run_dir: Path, protocol: str, background, device: str = "cpu") -> list[dict]:
    """Rows of one ``{results}/relight/{run}/{obj}`` folder (see the module docstring)."""
    run_files = RelightFolder(run_dir)
    info = io.read_json(run_files.record())
    oid = info["object"]
    L = Layout(results)
    meta = io.read_json(L.object_meta(oid))
    rows = []
    for light in info["lights"]:
        for view in info["target_views"]:
            pred = run_files.image(light, view)
            gt = L.object_image(oid, "targets", light, view)
            m = M.evaluate_files(pred, gt, protocol=protocol, background=background, device=device)
            rows.append({"dataset": meta["material_class"], "object": oid, "run": info["name"],
                         "method": info["method"], "variant": info["variant"], "views": int(info["views"]),
                         "k": info["k_percent"], "light": light, "view": view} | m)
    return rows


def evaluate(config: Config | dict, run_dirs: list[Path], out_dir: Path) -> tuple[Path, Path]:
    """Score every run folder; write the per-image CSV and the per-run summary into ``out_dir``."""
    config = frng_config.typed(config)
    results = Path(config.results)
    protocol = config.eval.protocol
    background = tuple(config.eval.background)
    rows = []
    for d in run_dirs:
        rows += evaluate_run(results, Path(d), protocol, background)
    if not rows:
        raise ValueError("frng evaluate: no relit images found (run `frng relight` first)")
    df = M.to_frame(rows)
    df = df[list(COLUMNS) + [c for c in df.columns if c not in COLUMNS]]
    per_image = M.write_csv(df, out_dir / PER_IMAGE)
    summary = M.aggregate(df, ["run", "method", "variant", "views", "k"])
    scales = {run: M.scale_log2(g) for run, g in df.groupby("run", sort=False)}
    summary["scale_log2"] = summary["run"].map(scales)
    brightness = {run: M.brightness_log2(g) for run, g in df.groupby("run", sort=False)}
    summary["brightness_log2"] = summary["run"].map(brightness)
    return per_image, M.write_csv(summary, out_dir / SUMMARY)


def run_dirs_of(config: Config | dict, objects: list[str]) -> list[Path]:
    """Every ``{results}/relight/{run}/{obj}`` folder the config plans for these test objects."""
    from frng.variants import runs

    L = Layout(frng_config.typed(config).results)
    return [Path(L.relight_run(r.name, oid)) for oid in objects for r in runs(config)]


def configure(parser: argparse.ArgumentParser) -> None:
    frng_config.add_config_argument(parser)
    parser.add_argument("--objects", nargs="*", help="test objects (default: the config's test split)")
    parser.add_argument("--out", help="metrics folder (default {results}/metrics)")


def run(args: argparse.Namespace) -> int:
    from frng.data import catalog

    config = frng_config.typed(frng_config.load(args.config))
    objects = args.objects or catalog.plan(config).split("test")
    out = Path(args.out or Layout(config.results).metrics_dir())
    per_image, summary = evaluate(config, run_dirs_of(config, objects), out)
    print(f"evaluate ({config.eval.protocol} protocol): wrote {per_image} and {summary}")
    print(M.read_csv(summary).to_string(index=False))
    return 0
