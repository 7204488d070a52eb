"""The baselines' tables and figures (stage ``frng baseline-tables``): the paper's Table 2 (``vs_dense``), Table 3
(``vs_image_based``) and the supplementary's views table (``views_nvs``), from ``frng baseline-eval``'s
``{results}/metrics/baselines_per_image.csv`` and ``baselines_timing.csv``.

================== ======== ================================================ ====================================
table              task     rows                                             reference of the differences
================== ======== ================================================ ====================================
``vs_dense``       relight  per dataset (material class; benchmark scenes    F-RNG (run ``full``, 6 views) on the
                            as ``{dataset}/{scene}``; then ``all``): F-RNG    same (object, light, view) images
                            and each dense per-scene method that relights
                            (``gsir`` at the largest view count, external
                            ``dense`` folders)
``vs_image_based`` relight  per dataset, then ``all``: F-RNG, the IDM         F-RNG, same images
                            re-shading baseline, external ``image`` folders
``views_nvs``      nvs      each per-scene method at each view count,         F-RNG's novel views (run
                            external dense folders, F-RNG from 6 views        ``full-nvs``), same images
================== ======== ================================================ ====================================

Every row names its ``source`` (``trained here`` / ``files``) and its ``views`` (input views; the image-based methods
take the target view's own photo: 1); ``n`` = images. F-RNG's row in a dataset group is over the images the group's
baselines cover (the per-scene baselines run on ``baselines.objects_per_class`` objects per class), so every
difference is paired: the row minus F-RNG over the same images, with its 95 % object-bootstrap interval
(:func:`frng.report.runs.diff_to`, :mod:`frng.report.stats`). Times: ``reconstruction_s`` = reconstruction seconds per
object (a per-scene fit; F-RNG's backbone + IDM + reconstruction), ``relight_ms_per_image``.

``baseline_findings``: what the three tables show, one row per comparison the paper draws, each a paired difference
(row minus reference over the same images) with its interval and a one-line verdict (:func:`findings`): every
Table 2 and Table 3 method against F-RNG, and each per-scene method at its fewest input views against its own most
(the supplementary's collapse), and at its fewest against F-RNG's 6 views.

Figures (``{results}/figures/baselines/{table}.png``): one row per shown image (the first object of each dataset
group, its first light and view), columns ground truth, F-RNG, each baseline of the table, PSNR in each cell.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np
import pandas as pd

from frng import metrics as M
from frng.baselines import registry
from frng.baselines.plan import FRNG_NVS_RUN, FRNG_RUN
from frng.report import tables as T
from frng.report.runs import IMAGE_KEYS, diff_to, image_means

FRNG, FRNG_NVS = FRNG_RUN, FRNG_NVS_RUN
METHOD_LABELS = {
    "F-RNG": "F-RNG (ours)",
    "idm-reshade": "IDM re-shading (image-based)",
}  # and each per-scene method's label (frng.baselines.registry)
COLUMNS = (
    "dataset",
    "method",
    "source",
    "views",
    "n",
    "psnr",
    "ssim",
    "lpips",
    "reconstruction_s",
    "relight_ms_per_image",
)
NOTE = (
    "Δ = the row minus F-RNG over the same images (object, light, view), 95% paired bootstrap interval over "
    "objects (2000 resamples); 'objects higher PSNR' counts objects whose mean PSNR is above F-RNG's."
)


def label(method: str, family: str) -> str:
    if method in METHOD_LABELS:
        return METHOD_LABELS[method]
    if method in registry.PER_SCENE:
        return registry.PER_SCENE[method].label
    return f"{method} ({'per-scene' if family == 'dense' else 'image-based'}, from files)"


def groups(df: pd.DataFrame) -> list[tuple[str, Callable[[pd.DataFrame], pd.DataFrame]]]:
    """(name, selector) per dataset (material class), per benchmark scene (``dataset/scene``), then ``all``."""
    out = []
    for ds in sorted(df["dataset"].astype(str).unique()):
        out.append((ds, lambda d, ds=ds: d[d["dataset"].astype(str) == ds]))
    scenes = df[df["scene"].fillna("").astype(str) != ""] if "scene" in df else df.iloc[:0]
    for (ds, sc), _ in scenes.groupby(["dataset", "scene"], sort=True):
        out.append((f"{ds}/{sc}", lambda d, ds=ds, sc=sc: d[(d["dataset"] == ds) & (d["scene"] == sc)]))
    out.append(("all", lambda d: d))
    return out


def _times(timing: pd.DataFrame, run: str, objects) -> dict:
    t = timing[(timing["run"] == run) & timing["object"].isin(list(objects))]
    return {
        "reconstruction_s": float(t["fit_seconds"].mean()) if len(t) else np.nan,
        "relight_ms_per_image": 1000.0 * float(t["relight_seconds_per_image"].mean()) if len(t) else np.nan,
    }


def _row(group: str, sub: pd.DataFrame, timing: pd.DataFrame, run: str) -> dict:
    first = sub.iloc[0]
    views = first["views"]
    return {
        "dataset": group,
        "method": label(str(first["method"]), str(first["family"])),
        "source": first["source"],
        "views": views if pd.notna(views) else np.nan,
        **image_means(sub),
        **_times(timing, run, sub["object"].unique()),
    }


def compare(
    df: pd.DataFrame, timing: pd.DataFrame, task: str, runs: Sequence[str], ref_run: str, by_group: bool
) -> pd.DataFrame:
    """Rows of ``runs`` (per group when ``by_group``) beside the reference run ``ref_run`` over the images they
    cover, each with its paired difference to the reference (module docstring)."""
    d = df[df["task"] == task]
    ref_all = d[d["run"] == ref_run]
    rows = []
    for name, pick in groups(d) if by_group else [("all", lambda x: x)]:
        subs = {r: pick(d[d["run"] == r]) for r in runs}
        subs = {r: s for r, s in subs.items() if len(s)}
        if runs and not subs:  # a group none of the table's baselines covers (F-RNG alone compares nothing)
            continue
        covered = pd.concat([s[list(IMAGE_KEYS)] for s in subs.values()]).drop_duplicates() if subs else None
        ref = pick(ref_all)
        if covered is not None:
            ref = ref.merge(covered, on=list(IMAGE_KEYS))
        if len(ref):
            rows.append(_row(name, ref, timing, ref_run) | {"method": METHOD_LABELS["F-RNG"]})
        for r, s in subs.items():
            row = _row(name, s, timing, r)
            if len(ref):
                row |= diff_to(s, ref)
            rows.append(row)
    out = pd.DataFrame(rows)
    cols = [c for c in COLUMNS if c in out.columns] + [c for c in T.diff_columns() if c in out.columns]
    return out.reindex(columns=cols).reset_index(drop=True)


def dense_runs(df: pd.DataFrame) -> list[str]:
    """Table 2's runs: the per-scene runs trained here that relight, at their largest view count, then the external
    dense ones (read from files)."""
    d = df[(df["task"] == "relight") & (df["family"] == "dense")]
    here, files = d[d["source"] != "files"], d[d["source"] == "files"]
    out = []
    for _method, g in here.groupby("method", sort=True):
        out += sorted(g.loc[g["views"] == g["views"].max(), "run"].unique())
    return out + list(dict.fromkeys(files["run"]))


def image_runs(df: pd.DataFrame) -> list[str]:
    d = df[(df["task"] == "relight") & (df["family"] == "image")]
    return list(dict.fromkeys(d["run"]))


def nvs_runs(df: pd.DataFrame) -> list[str]:
    """The views table's runs: the per-scene runs trained here by method and view count, then the external ones."""
    d = df[(df["task"] == "nvs") & (df["family"] != "frng")]
    d = d.assign(_files=d["source"] == "files", _v=d["views"].fillna(-1)).sort_values(["_files", "method", "_v"])
    return list(dict.fromkeys(d["run"]))


def verdict(diff: dict, name: str, ref: str) -> str:
    """One line saying which side a paired difference (``diff_to``'s columns: ``name`` minus ``ref``) resolves for
    PSNR and LPIPS: a side is named only where the 95 % interval excludes 0."""
    d, lo, hi = diff["dpsnr"], diff["dpsnr_lo"], diff["dpsnr_hi"]
    if not np.isfinite(d):
        return "no common images"
    if lo > 0:
        psnr = f"{name} higher PSNR by {d:.2f} dB"
    elif hi < 0:
        psnr = f"{ref} higher PSNR by {-d:.2f} dB"
    else:
        psnr = "PSNR not resolved (interval spans 0)"
    lo, hi = diff["dlpips_lo"], diff["dlpips_hi"]
    lp = f"{name} lower LPIPS" if hi < 0 else f"{ref} lower LPIPS" if lo > 0 else "LPIPS not resolved"
    return f"{psnr}; {lp}"


def _short(df: pd.DataFrame, run: str) -> str:
    sub = df[df["run"] == run]
    if not len(sub):
        return run
    views = sub["views"].iloc[0]
    name = label(str(sub["method"].iloc[0]), str(sub["family"].iloc[0])).split(" (")[0]
    return f"{name} ({int(views)} views)" if pd.notna(views) and str(sub["family"].iloc[0]) != "image" else name


def findings(df: pd.DataFrame) -> pd.DataFrame:
    """The ``baseline_findings`` rows (module docstring): what, task, vs (the reference), n (common images), the
    paired-difference columns and ``finding`` (:func:`verdict`)."""
    pairs = [("relight", r, FRNG) for r in dense_runs(df) + image_runs(df)]
    nvs = df[(df["task"] == "nvs") & (df["source"] != "files") & (df["family"] == "dense")]
    for _method, g in nvs.groupby("method", sort=True):
        by_views = g.groupby("views")["run"].first().sort_index()
        if len(by_views) > 1:
            pairs.append(("nvs", by_views.iloc[0], by_views.iloc[-1]))
        pairs.append(("nvs", by_views.iloc[0], FRNG_NVS))
    rows = []
    for task, run, ref in pairs:
        d = df[df["task"] == task]
        a, b = d[d["run"] == run], d[d["run"] == ref]
        n = len(a[list(IMAGE_KEYS)].merge(b[list(IMAGE_KEYS)], on=list(IMAGE_KEYS)))
        if not n:
            continue
        name, ref_name = _short(df, run), "F-RNG (6 views)" if ref in (FRNG, FRNG_NVS) else _short(df, ref)
        diff = diff_to(a, b)
        what = {"relight": "relighting", "nvs": "novel views under the input light"}[task]
        rows.append(
            {"what": f"{name}, {what}", "vs": ref_name, "n": n, **diff, "finding": verdict(diff, name, ref_name)}
        )
    cols = ["what", "vs", "n", *T.diff_columns(), "finding"]
    return pd.DataFrame(rows).reindex(columns=cols)


def caption(title: str, tier: str, background, sub: pd.DataFrame) -> str:
    proto = sub["protocol"].iloc[0] if len(sub) else "?"
    return (
        f"{title} Tier {tier}: {sub['object'].nunique()} object(s), {len(sub[list(IMAGE_KEYS)].drop_duplicates())} "
        f"images; {proto} metric protocol "
        f"(frng/metrics.py), background {list(background)}. Source: 'trained here' = fitted in this pipeline, "
        f"'files' = another method's outputs read from baselines.external. {NOTE}"
    )


def write_tables(per_image: Path, timing_csv: Path, out_dir: Path, tier: str, background) -> dict[str, dict]:
    """Write ``vs_dense``, ``vs_image_based`` and ``views_nvs`` (.csv/.md/.tex) into ``out_dir``. Returns
    {table: {ext: path}}."""
    df = M.read_csv(per_image)
    missing = [c for c in ("task", "run", "method", "family", "views", "source", "object", "dataset") if c not in df]
    if missing:
        raise KeyError(f"{per_image}: missing columns {missing}")
    if "scene" not in df:
        df["scene"] = ""
    timing = M.read_csv(timing_csv)
    out_dir = Path(out_dir)
    out = {}
    specs = [
        (
            "vs_dense",
            "relight",
            dense_runs(df),
            FRNG,
            True,
            "Relighting: F-RNG from 6 views vs dense-view per-scene relightable methods (paper Table 2).",
        ),
        (
            "vs_image_based",
            "relight",
            image_runs(df),
            FRNG,
            True,
            "Relighting: F-RNG vs image-based relighting of each target view's own photo (paper Table 3).",
        ),
        (
            "views_nvs",
            "nvs",
            nvs_runs(df),
            FRNG_NVS,
            False,
            "Novel-view synthesis under the input light: per-scene methods at each input-view count vs F-RNG's 6 "
            "views (paper supplementary, number of input views).",
        ),
    ]
    for name, task, runs, ref, by_group, title in specs:
        table = compare(df, timing, task, runs, ref, by_group)
        sub = df[(df["task"] == task) & df["run"].isin([*runs, ref])]
        out[name] = T.write_table(
            table,
            out_dir / name,
            best_within=["dataset"] if by_group else (),
            caption=caption(title, tier, background, sub),
            label=f"tab:{name}",
        )
    found = findings(df)
    stem = out_dir / "baseline_findings"
    if len(found):
        out["baseline_findings"] = T.write_table(
            found,
            stem,
            caption="What the baseline tables show: each comparison as the row minus the reference ('Δ vs') over the "
            f"images both have, tier {tier}. A side is named in 'Finding' only where the 95% interval excludes 0 (paired bootstrap over objects, "
            "2000 resamples); 'objects higher PSNR' counts objects whose mean PSNR is above the reference's.",
            label="tab:baseline_findings",
        )
    else:  # none to state: no file from an earlier run may stay behind looking current
        for ext in ("csv", "md", "tex"):
            stem.with_suffix(f".{ext}").unlink(missing_ok=True)
    return out


def figure_picks(df: pd.DataFrame, task: str, runs: Sequence[str], max_rows: int = 4) -> list[tuple[str, str, str]]:
    """(object, light, view) shown in a table's figure: per dataset any of the baselines ``runs[1:]`` covers, the
    first object every run of ``runs`` (the reference first) covers (else the first scored), its first light and
    view; at most ``max_rows``."""
    d = df[df["task"] == task]
    picks = []
    for ds in sorted(d["dataset"].astype(str).unique()):
        dd = d[d["dataset"].astype(str) == ds]
        objs = None
        for r in runs:
            o = set(dd.loc[dd["run"] == r, "object"])
            objs = o if objs is None else objs & o
        if len(runs) > 1 and not dd["run"].isin(list(runs[1:])).any():  # only the reference has this dataset
            continue
        cand = sorted(objs) if objs else sorted(dd["object"].unique())
        if not cand:
            continue
        first = dd[dd["object"] == cand[0]].iloc[0]
        picks.append((str(first["object"]), str(first["light"]), str(first["view"])))
    return picks[:max_rows]


def comparison_figure(
    df: pd.DataFrame,
    task: str,
    runs: Sequence[str],
    ref: str,
    load: Callable[[str | None, str, str, str], np.ndarray | None],
    out_png: Path,
    title: str,
    background=(1.0, 1.0, 1.0),
) -> dict | None:
    """A table's figure (module docstring). ``load(run, obj, light, view)`` -> (H, W, 4) linear RGBA (run None: the
    ground truth), or None where the run has no such image. Returns the layout, or None when nothing to show."""
    from frng.report.figures import comparison_grid

    order = [ref, *runs]
    picks = figure_picks(df, task, order)
    if not picks:
        return None
    d = df[df["task"] == task].set_index(["run", *IMAGE_KEYS])
    rows, caps, labels = [], [], []
    for oid, light, view in picks:
        row, cap = [load(None, oid, light, view)], [None]
        for r in order:
            key = (r, oid, light, view)
            row.append(load(r, oid, light, view) if key in d.index else None)
            cap.append(float(d.loc[key, "psnr"]) if key in d.index else None)
        rows.append(row)
        caps.append(cap)
        labels.append(f"{oid}\n{light}\n{view}")
    methods = {}
    for r in order:
        sub = df[df["run"] == r]
        methods[r] = (label(str(sub["method"].iloc[0]), str(sub["family"].iloc[0])) if len(sub) else r) + f" [{r}]"
    cols = ["ground truth", *[methods[r] for r in order]]
    return comparison_grid(out_png, rows, labels, cols, caps, title=title, background=background)
