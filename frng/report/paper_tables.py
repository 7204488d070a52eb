"""The paper's five tables from the per-image metrics and the relighting timings (stage :mod:`frng.stages.tables`,
``frng tables``).

Inputs: ``{results}/metrics/relight_per_image.csv`` (``frng evaluate``) and ``{results}/relight/timing/{obj}.json``
(``frng relight``). Outputs, each as ``.csv`` + ``.md`` + ``.tex`` (:func:`frng.report.tables.write_table`, best
value marked, the metric protocol and the tier named in the caption), in ``{results}/tables/``:

================ =================================================== =====================================
table            rows                                                columns
================ =================================================== =====================================
``vs_backbone``  per dataset (material class, then ``all``): F-RNG   dataset, method, psnr, ssim, lpips
                 (run ``full``) vs the backbone; footer: relighting  (+ relight_ms_per_image in the footer)
                 time per image
``ablation``     full, w/o fine-grained Gaussians, w/o IDM priors,   variant, psnr, ssim, lpips
                 w/o light-independence, w/o neural appearance
``views``        the full model fed 2, 4, 6, 8, 10 input views       views, psnr, ssim, lpips
``k``            K = 1, 2 (full), 4, 8 %                             k_percent, psnr, ssim, lpips
``timing``       F-RNG and the backbone, mean over test objects      method, reconstruction_s,
                                                                     relight_ms_per_image, resolution, spp,
                                                                     speedup (vs the backbone)
``ladder``       the quality ladder (:data:`LADDER_STEPS`): oracle   step, what, n, psnr, ssim, lpips,
                 references, backbone, F-RNG, F-RNG + oracle priors  scale_log2
                 (also reads ``{results}/metrics/backbone.csv``)
================ =================================================== =====================================

Metric values are means of per-image values (PSNR averaged in dB) over all test objects, lights and views.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from frng import io
from frng import metrics as M
from frng.config import Config, typed
from frng.report import tables as T
from frng.variants import BACKBONE, BASE_VARIANTS, ORACLE_RUN, RIG_VIEWS, VARIANTS

TABLES = tuple(T.TABLE_COLUMNS)
VARIANT_LABELS = {name: v.label for name, v in VARIANTS.items()}
METHOD_LABELS = {"F-RNG": "F-RNG (ours)", BACKBONE: "backbone (RelitLRM-style)"}


def _caption(title: str, config: Config, df: pd.DataFrame) -> str:
    n_obj = df["object"].nunique()
    return (f"{title} Tier {config.tier}: {n_obj} test object(s), {len(df)} images; "
            f"{df['protocol'].iloc[0]} metric protocol (see frng/metrics.py), background "
            f"{list(config.eval.background)}; mean over test objects, lights and views.")


def _metrics(df: pd.DataFrame, by: list[str]) -> pd.DataFrame:
    return M.aggregate(df, by)


def _idm_runs(df: pd.DataFrame) -> pd.DataFrame:
    """Rows of runs fed the configured IDM's priors (drops the ladder's oracle-prior run)."""
    return df[df["run"] != ORACLE_RUN]


def ablation_rows(df: pd.DataFrame) -> pd.DataFrame:
    """Per-image rows of the ablation runs (6 views, one of :data:`BASE_VARIANTS`)."""
    df = _idm_runs(df)
    return df[(df["views"] == RIG_VIEWS) & df["variant"].isin(BASE_VARIANTS)]


def k_rows(df: pd.DataFrame) -> pd.DataFrame:
    """Per-image rows of the K sweep (6 views, the full model and the ``k*`` variants)."""
    df = _idm_runs(df)
    v = df["variant"].astype(str)
    return df[(df["views"] == RIG_VIEWS) & (df["method"] == "F-RNG") & ((v == "full") | v.str.match(r"^k[0-9.]+$"))]


def views_rows(df: pd.DataFrame) -> pd.DataFrame:
    """Per-image rows of the #views sweep (the full model at every view count)."""
    df = _idm_runs(df)
    return df[df["variant"] == "full"]


def vs_backbone_table(df: pd.DataFrame, timings: list[dict]) -> tuple[pd.DataFrame, pd.DataFrame]:
    sub = df[df["run"].isin(["full", BACKBONE])].copy()
    sub["method"] = sub["method"].map(METHOD_LABELS)
    per = _metrics(sub, ["dataset", "method"])
    per = per.sort_values(["dataset", "method"], kind="stable")
    allrows = _metrics(sub.assign(dataset="all"), ["dataset", "method"])
    rows = pd.concat([per, allrows], ignore_index=True)
    ms = {METHOD_LABELS[m]: float(np.mean([t[m]["relight_ms_per_image"] for t in timings]))
          for m in ("F-RNG", BACKBONE)}
    return T.vs_backbone(rows, ms)


def ablation_table(df: pd.DataFrame) -> pd.DataFrame:
    out = _metrics(ablation_rows(df), ["variant"])
    order = {v: i for i, v in enumerate(BASE_VARIANTS)}
    out = out.sort_values("variant", key=lambda s: s.map(order))
    out["variant"] = out["variant"].map(VARIANT_LABELS)
    return out[list(T.TABLE_COLUMNS["ablation"])].reset_index(drop=True)


def views_table(df: pd.DataFrame) -> pd.DataFrame:
    out = _metrics(views_rows(df), ["views"]).sort_values("views")
    return out[list(T.TABLE_COLUMNS["views"])].reset_index(drop=True)


def k_table(df: pd.DataFrame) -> pd.DataFrame:
    out = _metrics(k_rows(df), ["k"]).rename(columns={"k": "k_percent"}).sort_values("k_percent")
    return out[list(T.TABLE_COLUMNS["k"])].reset_index(drop=True)


LADDER_STEPS = (  # (step, what, source, task/run, method); source "prior" = backbone.csv, "relight" = per-image
    ("a", "ground-truth depth + oracle colour (representation ceiling)", "prior", "relight", "gt-depth+oracle-colour"),
    ("b", "backbone geometry + oracle colour", "prior", "relight", "backbone-geometry+oracle-colour"),
    ("c", "backbone novel views (input light, held-out views)", "prior", "nvs", "backbone"),
    ("d", "backbone relighting", "relight", BACKBONE, None),
    ("e", "F-RNG relighting", "relight", "full", None),
    ("f", "F-RNG relighting with oracle (G-buffer) IDM priors", "relight", ORACLE_RUN, None),
    ("-", "trivial baseline: mean training image", "prior", "relight", "mean-image"),
)


def ladder_table(df: pd.DataFrame, prior: pd.DataFrame) -> pd.DataFrame:
    """The quality ladder (rows of :data:`LADDER_STEPS` present in the inputs): where the dB go, on the held-out
    relighting images (row c: the held-out input-light views). ``scale_log2``: :func:`frng.metrics.scale_log2`;
    ``brightness_log2``: :func:`frng.metrics.brightness_log2` (relighting rows only).
    LPIPS where the input has it (prior evaluations written before it was recorded leave it NaN)."""
    rows = []
    for step, what, source, key, method in LADDER_STEPS:
        if source == "prior":
            sub = prior[(prior["task"] == key) & (prior["method"] == method)]
        else:
            sub = df[df["run"] == key]
        if not len(sub):
            continue
        rows.append({"step": step, "what": what, "n": len(sub), "psnr": sub["psnr"].mean(),
                     "ssim": sub["ssim"].mean(), "lpips": sub["lpips"].mean() if "lpips" in sub else np.nan,
                     "scale_log2": M.scale_log2(sub), "brightness_log2": M.brightness_log2(sub)})
    return pd.DataFrame(rows, columns=list(T.TABLE_COLUMNS["ladder"]))


def timing_table(timings: list[dict]) -> pd.DataFrame:
    rows = []
    for m in ("F-RNG", BACKBONE):
        rows.append({"method": METHOD_LABELS[m],
                     "reconstruction_s": float(np.mean([t[m]["reconstruction_s"] for t in timings])),
                     "relight_ms_per_image": float(np.mean([t[m]["relight_ms_per_image"] for t in timings])),
                     "resolution": int(timings[0]["resolution"]),
                     "spp": timings[0]["spp"] if m == "F-RNG" else np.nan})
    return T.timing(pd.DataFrame(rows), reference=METHOD_LABELS[BACKBONE])


def write_tables(config: Config | dict, per_image_csv: Path, timing_files: list[Path], out_dir: Path,
                 prior_csv: Path) -> dict[str, dict]:
    """Write the tables (see the module docstring). Returns {table: {"csv"|"md"|"tex": path}}."""
    config = typed(config)
    df = M.read_csv(per_image_csv)
    missing = [c for c in ("dataset", "object", "run", "method", "variant", "views", "k", "psnr", "ssim", "lpips",
                           "protocol") if c not in df.columns]
    if missing:
        raise KeyError(f"{per_image_csv}: missing columns {missing}")
    timings = [io.read_json(p) for p in timing_files]
    if not timings:
        raise ValueError("frng tables: no relighting timing files given")
    device = sorted({t["device"] for t in timings})
    out = {}
    rows, footer = vs_backbone_table(df, timings)
    out["vs_backbone"] = T.write_table(
        rows, out_dir / "vs_backbone", footer=footer, best_within=["dataset"],
        caption=_caption("Relighting quality: F-RNG vs the backbone it builds on (datasets = material classes).",
                         config, df[df["run"].isin(["full", BACKBONE])]), label="tab:vs_backbone")
    out["ablation"] = T.write_table(
        ablation_table(df), out_dir / "ablation",
        caption=_caption("Ablation of F-RNG's components.", config, ablation_rows(df)),
        label="tab:ablation")
    out["views"] = T.write_table(
        views_table(df), out_dir / "views",
        caption=_caption("Number of input views (the same trained full model).", config,
                         views_rows(df)), label="tab:views")
    out["k"] = T.write_table(
        k_table(df), out_dir / "k",
        caption=_caption("Top-K salient patches (K in % of a view's patches; 2% is the full model).", config,
                         k_rows(df)), label="tab:k")
    prior = pd.read_csv(prior_csv)
    out["ladder"] = T.write_table(
        ladder_table(df, prior), out_dir / "ladder", decimals={"scale_log2": 2, "brightness_log2": 2},
        caption=(f"Quality ladder: where the dB go. Aligned protocol on the held-out relighting images (row c: the "
                 f"held-out input-light views); scale_log2 = median over images and channels of |log2| of the "
                 f"per-channel least-squares scale the protocol applied; brightness_log2 = the same of the ratio of "
                 f"means (ground truth over prediction). Tier {config.tier}."), label="tab:ladder")
    t = timing_table(timings)
    out["timing"] = T.write_table(
        t, out_dir / "timing",
        caption=(f"Reconstruction and relighting time per image, measured side by side in the same job on "
                 f"{', '.join(device)} at {int(t['resolution'].iloc[0])} px, mean over {len(timings)} test "
                 f"object(s); F-RNG renders with {t['spp'].iloc[0]:.0f} light samples per pixel, the backbone "
                 f"runs one full denoising pass per light. Tier {config.tier}."), label="tab:timing")
    return out
