"""The per-image rows of the relighting runs as the tables read them (:mod:`frng.report.paper_tables`,
:mod:`frng.report.ladder`, :mod:`frng.report.baseline_tables`): a run and its training-seed repeats (``run@s{seed}``,
:mod:`frng.plan.variants`), their per-image means over seeds, the metric cells every table row carries
(:func:`image_means`) and the paired differences with their bootstrap intervals (:func:`diff_to`, over test objects
and, where a run has several, training seeds)."""

from __future__ import annotations

import numpy as np
import pandas as pd

from frng import metrics as M
from frng.plan.variants import SEED_SEP, split_seed
from frng.report import stats as S
from frng.report import tables as T

IMAGE_KEYS = ("object", "light", "view")


def base_run(run: str) -> str:
    """The run a training-seed run repeats (``full@s1`` -> ``full``; others unchanged)."""
    return split_seed(str(run))[0] if SEED_SEP in str(run) else str(run)


def plain_runs(df: pd.DataFrame) -> pd.DataFrame:
    """Rows of the runs trained with the models' own seed (no ``@s{seed}`` runs)."""
    return df[~df["run"].astype(str).str.contains(SEED_SEP, regex=False)]


def seed_runs(df: pd.DataFrame, run: str) -> dict[str, pd.DataFrame]:
    """{run name: its per-image rows} of ``run`` and its training-seed repeats (``run@s{seed}``)."""
    runs = df["run"].astype(str)
    return {r: df[runs == r] for r in dict.fromkeys(runs[runs.map(base_run) == run])}


def seed_mean(df: pd.DataFrame, run: str) -> pd.DataFrame:
    """Per-image rows of ``run`` averaged over its training seeds (one row per object, light and view; metric
    columns, PSNR interior and the scale/brightness columns averaged; ``run`` = the plain name)."""
    parts = seed_runs(df, run)
    if not parts:
        return df.iloc[:0]
    sub = pd.concat(parts.values(), ignore_index=True)
    num = [c for c in sub.columns if c in M.METRICS or c.startswith(("psnr_", "scale_", "brightness_"))]
    first = sub.drop_duplicates(list(IMAGE_KEYS)).set_index(list(IMAGE_KEYS)).drop(columns=num)
    mean = sub.groupby(list(IMAGE_KEYS), sort=False)[num].mean()
    out = first.join(mean).reset_index()
    out["run"] = run
    if "variant" in out:
        out["variant"] = out["variant"].astype(str).map(lambda v: split_seed(v)[0])
    return out[[c for c in df.columns if c in out.columns]]


def seed_parts(df: pd.DataFrame, run: str, select=lambda d: d) -> dict[str, pd.DataFrame]:
    """{run name: per-image rows} of ``run`` and of each of its training-seed repeats, narrowed by ``select``, empty
    ones left out: what :func:`seed_columns` spreads and :func:`diff_to` bootstraps over seeds as well as objects."""
    parts = {r: select(d) for r, d in seed_runs(df, run).items()}
    return {r: d for r, d in parts.items() if len(d)}


def image_means(sub: pd.DataFrame) -> dict:
    """``n`` (images) and the mean PSNR / PSNR interior / SSIM / LPIPS of per-image rows (PSNR interior and LPIPS NaN
    where the rows have none): the metric cells every table row carries (each table shows its own)."""
    return {
        "n": len(sub),
        "psnr": sub["psnr"].mean(),
        "psnr_interior": sub["psnr_interior"].mean() if "psnr_interior" in sub else np.nan,
        "ssim": sub["ssim"].mean(),
        "lpips": sub["lpips"].mean() if "lpips" in sub else np.nan,
    }


def diff_to(rows, ref, metrics=T.DIFF_METRICS) -> dict:
    """The paired-difference columns (:func:`frng.report.tables.diff_columns`) of ``metrics`` of ``rows`` minus
    ``ref``, matched on object, light and view (:func:`frng.report.stats.paired`). Either may be a list of per-seed
    frames (:func:`seed_parts`): the interval then also resamples the training seeds."""
    out = {}
    frames = [*(rows if isinstance(rows, list) else [rows]), *(ref if isinstance(ref, list) else [ref])]
    for m in metrics:
        if any(m not in f.columns for f in frames):  # per-image rows written before the metric existed
            out |= {f"d{m}": np.nan, f"d{m}_lo": np.nan, f"d{m}_hi": np.nan}
            continue
        r = S.paired(rows, ref, m, IMAGE_KEYS)
        out |= {f"d{m}": r.diff, f"d{m}_lo": r.lo, f"d{m}_hi": r.hi}
        if m == "psnr":
            out |= {"better": r.better, "objects": r.objects}
    return out


def seed_columns(df: pd.DataFrame, run: str, ref_run: str | None, select=lambda d: d) -> dict:
    """``seeds``, ``seed_spread_psnr``, ``seed_spread_dpsnr`` of ``run`` (see the module docstring); ``select``
    narrows each seed's rows (e.g. to one dataset)."""
    parts = seed_parts(df, run, select)
    if not parts:
        return {"seeds": np.nan, "seed_spread_psnr": np.nan, "seed_spread_dpsnr": np.nan}
    means = [d["psnr"].mean() for d in parts.values()]
    out = {
        "seeds": len(parts),
        "seed_spread_psnr": float(np.ptp(means)) if len(parts) > 1 else np.nan,
        "seed_spread_dpsnr": np.nan,
    }
    if ref_run is not None and len(parts) > 1:
        refs = {r: select(d) for r, d in seed_runs(df, ref_run).items()}
        diffs = []
        for r, d in parts.items():
            _, seed = split_seed(r) if SEED_SEP in r else (r, None)
            ref = refs.get(ref_run if seed is None else f"{ref_run}{SEED_SEP}{seed}", refs.get(ref_run))
            if ref is not None and len(ref):
                diffs.append(S.paired(d, ref, "psnr", IMAGE_KEYS).diff)
        if len(diffs) > 1:
            out["seed_spread_dpsnr"] = float(np.ptp(diffs))
    return out
