"""The quality ladder (table ``ladder``, :data:`LADDER_STEPS`): where the dB go on the held-out relighting images,
from the targets' own noise through the oracle references and the backbone to F-RNG, F-RNG+ and F-RNG+'s Lambertian
base, then the light-sensitivity rows ``s*`` (:func:`sensitivity_rows`); and the ladder per material class
(:func:`ladder_by_class`). Written by :func:`frng.report.paper_tables.write_tables`."""

from __future__ import annotations

import numpy as np
import pandas as pd

from frng import metrics as M
from frng.plan.variants import BACKBONE, BASE_RUN, KNOWN_LIGHT_RUN, ORACLE_RUN, PLUS
from frng.report import tables as T
from frng.report.runs import diff_to, image_means, plain_runs

GROUND_TRUTH = "ground-truth"  # frng.apps.scoring.GROUND_TRUTH
TARGETS_METHOD = "targets-vs-high-spp"  # frng.data.noise_floor.LADDER_METHODS["tier"]: the ladder's step 0
REFERENCE_HALF_METHOD = "high-spp-reference-half"  # frng.data.noise_floor.LADDER_METHODS["reference-half"]: step 0r


LADDER_STEPS = (  # (step, what, source, task/run, method, reference step); source "prior" = backbone.csv
    (
        "0r",
        "the reference's own noise: one of its two high-spp renders against the other (their mean: ~6 dB above)",
        "prior",
        "relight",
        REFERENCE_HALF_METHOD,
        None,
    ),
    (
        "0",
        "the targets' noise floor: curated as the tier curates, against a high-spp render of the same views",
        "prior",
        "relight",
        TARGETS_METHOD,
        None,
    ),
    (
        "a",
        "ground-truth depth (pixel-footprint surfels) + oracle colour",
        "prior",
        "relight",
        "gt-depth+oracle-colour",
        None,
    ),
    ("b", "backbone geometry + oracle colour", "prior", "relight", "backbone-geometry+oracle-colour", None),
    ("c", "backbone novel views (input light, held-out views)", "prior", "nvs", "backbone", None),
    ("d", "backbone relighting", "relight", BACKBONE, None, None),
    ("e", "F-RNG relighting (the paper's form)", "relight", "full", None, "d"),
    ("f", "F-RNG relighting with oracle (G-buffer) IDM priors", "relight", ORACLE_RUN, None, "e"),
    ("e+", "F-RNG+ relighting (the project's additions on)", "relight", PLUS, None, "e"),
    (
        "g",
        "F-RNG+'s Lambertian base alone (decoder residual, attenuation, specular base dropped)",
        "relight",
        BASE_RUN,
        None,
        "e+",
    ),
    ("h", "oracle: F-RNG+ told the input views' light (not the paper's task)", "relight", KNOWN_LIGHT_RUN, None, "e+"),
    ("-", "trivial baseline: mean training image", "prior", "relight", "mean-image", None),
)


SENSITIVITY_STEPS = (  # (step, method label, run in the per-image / cross-light CSVs)
    ("s1", "backbone", BACKBONE),
    ("s2", "F-RNG", "full"),
    ("s2+", "F-RNG+", PLUS),
    ("s3", "ground truth", GROUND_TRUTH),
)


def sensitivity_rows(df: pd.DataFrame, cross: pd.DataFrame | None) -> list[dict]:
    """Light sensitivity per method (:data:`SENSITIVITY_STEPS`): psnr/ssim/lpips of the method's render for one
    test light scored against the ground truth of another test light (same object and view; ``cross``:
    ``relight_cross_light.csv``), and the paired difference right light minus wrong light with its interval
    (``d*``; ``better``: objects that score higher against the right light). The ground truth's right-light score
    is the ground truth against itself (its ``scored_against == light`` rows): its SSIM and LPIPS differences are
    finite, its PSNR difference is not (identical images; the metric's cap is not a measurement), so its ``dpsnr``
    columns are left empty and its wrong-light PSNR is the number to read (how different the test lights are)."""
    if cross is None or not len(cross):
        return []
    rows = []
    for step, label, run in SENSITIVITY_STEPS:
        c = cross[cross["run"] == run]
        wrong = c[c["scored_against"] != c["light"]]
        right = c[c["scored_against"] == c["light"]] if run == GROUND_TRUTH else df[df["run"] == run]
        if not len(wrong) or not len(right):
            continue
        rows.append(
            {
                "step": step,
                "what": f"light sensitivity: {label} (scored against another test light)",
                "n": len(wrong),
                "psnr": wrong["psnr"].mean(),
                "ssim": wrong["ssim"].mean(),
                "lpips": wrong["lpips"].mean(),
                "vs": "right light",
            }
            | diff_to(right, wrong)
        )
        if run == GROUND_TRUTH:
            rows[-1] |= {"dpsnr": np.nan, "dpsnr_lo": np.nan, "dpsnr_hi": np.nan}
    return rows


def ladder_table(df: pd.DataFrame, prior: pd.DataFrame, cross: pd.DataFrame | None = None) -> pd.DataFrame:
    """The quality ladder (rows of :data:`LADDER_STEPS` present in the inputs): where the dB go, on the held-out
    relighting images (row c: the held-out input-light views). ``psnr_interior``: the mean of the per-image
    ``psnr_interior`` (:func:`frng.metrics.evaluate_pair`: the foreground without its silhouette rim; NaN for
    inputs written before it was recorded); ``silhouette_iou``: the mean of the per-image
    :func:`frng.metrics.silhouette_iou` (NaN likewise); ``depth_error``: the mean of the prior rows' per-object
    :func:`frng.priors.evaluate.depth_error` (the relighting runs' rows: NaN); ``scale_log2``: :func:`frng.metrics.scale_log2`;
    ``brightness_log2``: :func:`frng.metrics.brightness_log2` (relighting rows only).
    LPIPS where the input has it (prior evaluations written before it was recorded leave it NaN). Relighting rows
    with a reference step (``vs``) carry the paired difference to it; then the light-sensitivity rows
    (:func:`sensitivity_rows`). The models' own seed only."""
    df = plain_runs(df)
    rows, subs = [], {}
    for step, what, source, key, method, ref in LADDER_STEPS:
        if source == "prior":
            sub = prior[(prior["task"] == key) & (prior["method"] == method)]
        else:
            sub = df[df["run"] == key]
        if not len(sub):
            continue
        subs[step] = sub
        row = {
            "step": step,
            "what": what,
            **image_means(sub),
            "silhouette_iou": sub["silhouette_iou"].mean() if "silhouette_iou" in sub else np.nan,
            "depth_error": sub["depth_error"].mean() if "depth_error" in sub else np.nan,
            "scale_log2": M.scale_log2(sub),
            "brightness_log2": M.brightness_log2(sub),
        }
        if ref is not None and ref in subs:
            row |= {"vs": ref} | diff_to(sub, subs[ref])
        rows.append(row)
    rows += sensitivity_rows(df, cross)
    out = pd.DataFrame(rows)
    main = list(T.TABLE_COLUMNS["ladder"])
    rest = [c for c in ["vs", *T.diff_columns()] if c in out.columns]
    return out.reindex(columns=main + rest)


def split_ladder(ladder: pd.DataFrame) -> tuple[pd.DataFrame, pd.DataFrame]:
    """(the ladder's steps, its light-sensitivity rows ``s*``): written as the table and its unmarked footer."""
    s = ladder["step"].astype(str).str.match(r"^s[0-9]+\+?$")
    return ladder[~s].reset_index(drop=True), ladder[s].reset_index(drop=True)


def ladder_by_class(df: pd.DataFrame, prior: pd.DataFrame, cross: pd.DataFrame | None = None) -> pd.DataFrame:
    """:func:`ladder_table` for each material class (``dataset``: diffuse, fur, specular, ...; rows: class, then step;
    the light-sensitivity rows ``s*`` included): where each class's dB go, and how far its geometry is from the
    G-buffer (``silhouette_iou``, ``depth_error``). The prior rows carry no class: an object's class is the one its
    relighting rows have."""
    classes = df.groupby("object")["dataset"].first() if len(df) else pd.Series(dtype=object)
    parts = []
    for ds in sorted(set(classes)):
        objs = set(classes.index[classes == ds])
        pick = lambda d, objs=objs: None if d is None else d[d["object"].isin(objs)]  # noqa: E731
        t = ladder_table(pick(df), pick(prior), pick(cross))
        if len(t):
            parts.append(t.assign(dataset=ds))
    out = pd.concat(parts, ignore_index=True) if parts else pd.DataFrame(columns=["dataset"])
    main = list(T.TABLE_COLUMNS["ladder_by_class"])
    rest = [c for c in ["vs", *T.diff_columns()] if c in out.columns]
    return out.reindex(columns=main + rest).reset_index(drop=True)
