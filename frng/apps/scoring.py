"""Per-image relighting metrics of every run of every test object (stage ``frng evaluate``, rule ``evaluate``).

Reads what ``frng relight`` wrote (``{results}/relight/{run}/{obj}/run.json`` and ``{light}/{view}.exr``) and
the ground truth (``{results}/objects/{obj}/targets/{light}/{view}.exr``), scores every image with
:func:`frng.metrics.evaluate_pair` under the config's ``eval.protocol`` (``aligned``: per-channel least-squares
scale, foreground PSNR/SSIM; ``plain``: whole image, no scaling) and ``eval.background``, and writes

- ``{results}/metrics/relight_per_image.csv``: one row per image, columns ``dataset`` (the object's material
  class: diffuse / specular / fur), ``object, run, method, variant, views, k, light, view, psnr, psnr_interior
  (the foreground without its silhouette rim), ssim, lpips, protocol``, the protocol's ``scale_r/g/b``, the ratio
  of means ``brightness_r/g/b`` and ``fg_fraction``;
- ``{results}/metrics/relight_summary.csv``: means per ``run`` (plus ``n``), via :func:`frng.metrics.aggregate`,
  ``scale_log2`` (:func:`frng.metrics.scale_log2`: how much colour repair the aligned protocol did per run) and
  ``brightness_log2`` (:func:`frng.metrics.brightness_log2`: how far off the brightness is, by the ratio of means).

- ``{results}/metrics/relight_cross_light.csv``: the light-sensitivity check (the quality ladder's rows ``s``):
  every image of the runs in :data:`SENSITIVITY_RUNS` (the backbone, F-RNG's ``full``) and the ground truth itself
  (run ``ground-truth``), each rendered for test light ``light``, scored against the ground truth of ANOTHER test
  light of the same object and view, ``scored_against`` = the next light in the object's list (cyclic,
  :func:`frng.metrics.other_light`); same protocol and columns as the per-image CSV. The ground truth's rows scored against
  their own light (``scored_against == light``) are there too, so its right-light score is a CSV row as well.
  Objects with a single test light have no such rows.

The per-image CSV also records each run's training ``seed`` (empty: the models' seed) and ``decoder`` (``base``:
the Lambertian base alone, run ``full-base``). Every table (``frng tables``) is recomputed from these CSVs.
"""

from __future__ import annotations

from pathlib import Path

from frng import io
from frng import metrics as M
from frng.metrics import EvalConfig, other_light
from frng.plan.layout import Layout, RelightFolder

PER_IMAGE = "relight_per_image.csv"
SUMMARY = "relight_summary.csv"
CROSS_LIGHT = "relight_cross_light.csv"
COLUMNS = (
    "dataset",
    "object",
    "run",
    "method",
    "variant",
    "views",
    "k",
    "seed",
    "decoder",
    "light",
    "view",
    "psnr",
    "psnr_interior",
    "silhouette_iou",
    "ssim",
    "lpips",
    "protocol",
)
CROSS_COLUMNS = (
    "dataset",
    "object",
    "run",
    "method",
    "light",
    "scored_against",
    "view",
    "psnr",
    "ssim",
    "lpips",
    "protocol",
)
SENSITIVITY_RUNS = ("backbone", "full", "plus")  # + the ground truth (GROUND_TRUTH)
GROUND_TRUTH = "ground-truth"


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
            rows.append(
                {
                    "dataset": meta["material_class"],
                    "object": oid,
                    "run": info["name"],
                    "method": info["method"],
                    "variant": info["variant"],
                    "views": int(info["views"]),
                    "k": info["k_percent"],
                    "seed": info.get("seed"),
                    "decoder": info.get("decoder", "full"),
                    "light": light,
                    "view": view,
                }
                | m
            )
    return rows


def cross_light_run(
    results: Path, run_dir: Path, protocol: str, background, device: str = "cpu", ground_truth: bool = False
) -> list[dict]:
    """Light-sensitivity rows of one run folder (see the module docstring): each image scored against the ground
    truth of :func:`frng.metrics.other_light`. ``ground_truth``: score the ground truth of the run's images instead of the
    run's renders (run ``ground-truth``), against the other light and against its own."""
    info = io.read_json(RelightFolder(run_dir).record())
    oid = info["object"]
    L = Layout(results)
    meta = io.read_json(L.object_meta(oid))
    lights = list(info["lights"])
    if len(lights) < 2:
        return []
    rows = []
    for light in lights:
        wrong = other_light(lights, light)
        for view in info["target_views"]:
            pred = (
                L.object_image(oid, "targets", light, view)
                if ground_truth
                else RelightFolder(run_dir).image(light, view)
            )
            for against in [wrong, light] if ground_truth else [wrong]:
                m = M.evaluate_files(
                    pred,
                    L.object_image(oid, "targets", against, view),
                    protocol=protocol,
                    background=background,
                    device=device,
                )
                rows.append(
                    {
                        "dataset": meta["material_class"],
                        "object": oid,
                        "run": GROUND_TRUTH if ground_truth else info["name"],
                        "method": GROUND_TRUTH if ground_truth else info["method"],
                        "light": light,
                        "scored_against": against,
                        "view": view,
                    }
                    | m
                )
    return rows


def evaluate(results: str | Path, eval_cfg: EvalConfig, run_dirs: list[Path], out_dir: Path) -> tuple[Path, Path]:
    """Score every run folder of the results folder ``results`` under the config's ``eval`` section; write the
    per-image CSV, the per-run summary (returned) and the light-sensitivity CSV into ``out_dir``."""
    results = Path(results)
    protocol = eval_cfg.protocol
    background = tuple(eval_cfg.background)
    rows = []
    for d in run_dirs:
        rows += evaluate_run(results, Path(d), protocol, background)
    if not rows:
        raise ValueError("frng evaluate: no relit images found (run `frng relight` first)")
    df = M.to_frame(rows)
    df = df[list(COLUMNS) + [c for c in df.columns if c not in COLUMNS]]
    per_image = M.write_csv(df, out_dir / PER_IMAGE)
    cross = []
    for d in run_dirs:
        if Path(d).parent.name in SENSITIVITY_RUNS:
            cross += cross_light_run(results, Path(d), protocol, background)
            if Path(d).parent.name == "full":
                cross += cross_light_run(results, Path(d), protocol, background, ground_truth=True)
    cf = M.to_frame(cross)
    cf = cf.reindex(columns=list(CROSS_COLUMNS) + [c for c in cf.columns if c not in CROSS_COLUMNS])
    M.write_csv(cf, out_dir / CROSS_LIGHT)
    summary = M.aggregate(df, ["run", "method", "variant", "views", "k"])
    scales = {run: M.scale_log2(g) for run, g in df.groupby("run", sort=False)}
    summary["scale_log2"] = summary["run"].map(scales)
    brightness = {run: M.brightness_log2(g) for run, g in df.groupby("run", sort=False)}
    summary["brightness_log2"] = summary["run"].map(brightness)
    return per_image, M.write_csv(summary, out_dir / SUMMARY)


def run_dirs_of(config, objects: list[str]) -> list[Path]:
    """Every ``{results}/relight/{run}/{obj}`` folder the config (typed or the validated dict) plans for these test
    objects."""
    from frng.plan.variants import runs

    results = config["results"] if isinstance(config, dict) else config.results
    return [Path(Layout(results).relight_run(r.name, oid)) for oid in objects for r in runs(config)]
