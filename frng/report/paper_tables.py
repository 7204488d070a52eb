"""The paper's five tables, the quality ladder and its per-class Lambertian part, from the per-image metrics and the
relighting timings (stage :mod:`frng.stages.tables`, ``frng tables``).

Inputs: ``{results}/metrics/relight_per_image.csv`` and ``relight_cross_light.csv`` (``frng evaluate``),
``{results}/metrics/backbone.csv`` (``frng eval-backbone``) and ``{results}/relight/timing/{obj}.json``
(``frng relight``). Outputs, each as ``.csv`` + ``.md`` + ``.tex`` (:func:`frng.report.tables.write_table`, best
value marked, the metric protocol and the tier named in the caption), in ``{results}/tables/``:

================ =================================================== =====================================
table            rows                                                reference row of the differences
================ =================================================== =====================================
``vs_backbone``  per dataset (material class, then ``all``): F-RNG   the backbone, same dataset
                 (run ``full``) vs the backbone; footer: relighting
                 time per image
``ablation``     full, w/o fine-grained Gaussians, w/o IDM priors,   the full model
                 w/o light-independence, w/o neural appearance
``views``        the full model fed 2, 4, 6, 8, 10 input views       6 views (the rig)
``k``            K = 1, 2, 4, 8 %                                    the full model's K
``timing``       F-RNG and the backbone, mean over test objects      (speedup vs the backbone)
``ladder``       the quality ladder (:mod:`.ladder`): the      ``vs`` column: e vs d, f and g vs e;
                 targets' noise floor (steps 0r, 0: ``noise_csv``),  rows ``s*``: the same method scored
                 oracle references, backbone, F-RNG, F-RNG +         against the right light
                 oracle priors, F-RNG's Lambertian base alone,
                 and the light-sensitivity rows ``s*``
                 (:func:`.ladder.sensitivity_rows`)
``lambertian``   per dataset: F-RNG and its Lambertian base alone    F-RNG, same dataset
                 (run ``full-base``)
``*_by_light``   ``vs_backbone``, ``ablation`` and ``ladder`` per     as in the table, within the family
                 family of the target light (``light_family``: sky,
                 hdri, studio, user; the dataset plan's
                 ``EnvMapSpec.family``, passed as ``families``)
``ladder_by_     ``ladder`` per material class (``dataset``), its    as in the ladder, within the class
class``          geometry columns per class
``vs_backbone_   ``vs_backbone`` per source of the test object       the backbone, same source
by_source``      (``object_source``: procedural, primitives, pybullet,
                 libero, objaverse, user: ``ObjectRecord.source``)
================ =================================================== =====================================

Metric columns (psnr, ssim, lpips) are means of per-image values (PSNR averaged in dB) over all test objects,
lights and views. Every row compared with a reference row also carries the paired difference (row minus reference,
over the same images) with its 95% bootstrap interval over test objects (:func:`frng.report.stats.paired_bootstrap`,
2000 resamples, seed 0) as ``d{metric}``, ``d{metric}_lo``, ``d{metric}_hi``, and ``better`` / ``objects``
(objects where the row's mean PSNR is higher / all objects).

Training seeds (``train.seeds``, :mod:`frng.plan.variants`): ``vs_backbone`` and ``ablation`` average each image over
the seeds of every trained row (``full``, ``full@s1``, ...) before anything else, and add ``seeds``,
``seed_spread_psnr`` (max - min over seeds of the row's mean PSNR) and ``seed_spread_dpsnr`` (max - min over seeds
of the row's mean PSNR difference to its reference, seed by seed where the reference has that seed). Their
intervals resample the training seeds as well as the objects (:func:`frng.report.stats.paired_bootstrap` with one
frame per seed, :func:`frng.report.runs.seed_parts`), so they contain the spread between training runs. ``views``, ``k``,
``ladder`` and ``lambertian`` use the models' own seed (the plain run names) only.
"""

from __future__ import annotations

import functools
from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np
import pandas as pd

from frng import io
from frng import metrics as M
from frng.plan.variants import (
    ABLATION_VARIANTS,
    ADDITIONS,
    BACKBONE,
    BASE_RUN,
    KNOWN_LIGHT_RUN,
    LEAVE_OUT_VARIANTS,
    ORACLE_RUN,
    PLUS,
    PLUS_METHOD,
    RIG_VIEWS,
    VARIANTS,
)
from frng.report import tables as T
from frng.report.ladder import ladder_by_class, ladder_table, split_ladder
from frng.report.runs import base_run, diff_to, image_means, plain_runs, seed_columns, seed_mean, seed_parts

TABLES = tuple(T.TABLE_COLUMNS)
VARIANT_LABELS = {name: v.label for name, v in VARIANTS.items()}
METHOD_LABELS = {
    "F-RNG": "F-RNG (ours)",
    PLUS_METHOD: "F-RNG+ (ours, with the additions)",
    BACKBONE: "backbone (RelitLRM-style)",
}
# the rows of the vs-backbone tables: (run, timing key), the paper's F-RNG first; F-RNG+ where it was trained
HEADLINE_RUNS = (("full", "F-RNG"), (PLUS, PLUS_METHOD))
BASE_LABEL = "Lambertian base only"
DIFF_NOTE = (
    "Δ = the row minus its reference row over the same images, with a 95% paired bootstrap interval over "
    "test objects (2000 resamples; where a row has several training seeds, the seeds are resampled too); "
    "'objects higher PSNR' counts objects whose mean PSNR is above the reference's."
)


def _caption(title: str, tier: str, background: Sequence[float], df: pd.DataFrame) -> str:
    n_obj = df["object"].nunique()
    if not len(df):
        return f"{title} Tier {tier}: no images (the runs were not made)."
    return (
        f"{title} Tier {tier}: {n_obj} test object(s), {len(df)} images; "
        f"{df['protocol'].iloc[0]} metric protocol (see frng/metrics.py), background "
        f"{list(background)}; mean over test objects, lights and views. {DIFF_NOTE}"
    )


def _write(out_dir: Path, name: str, table: pd.DataFrame, caption: str, **kw) -> dict:
    """:func:`frng.report.tables.write_table` of ``table`` as ``out_dir/name`` with label ``tab:name``."""
    return T.write_table(table, out_dir / name, caption=caption, label=f"tab:{name}", **kw)


def _captioned(out_dir, tier, background, name: str, frame: pd.DataFrame, title: str, rows: pd.DataFrame, **kw):
    """:func:`_write` with the standard caption (:func:`_caption` of ``title`` over the images ``rows``)."""
    return _write(out_dir, name, frame, _caption(title, tier, background, rows), **kw)


def _metrics(df: pd.DataFrame, by: list[str]) -> pd.DataFrame:
    return M.aggregate(df, by)


# -- row selections ----------------------------------------------------------------------------------------


def _idm_runs(df: pd.DataFrame) -> pd.DataFrame:
    """Rows of the paper's runs: the configured IDM's priors, the full decoder, the models' own seed (drops the
    ladder's oracle-prior and Lambertian-base runs and the other training seeds)."""
    df = plain_runs(df)
    return df[~df["run"].isin([ORACLE_RUN, BASE_RUN, KNOWN_LIGHT_RUN])]


def ablation_rows(df: pd.DataFrame) -> pd.DataFrame:
    """Per-image rows of the ablation runs (6 views, one of :data:`ABLATION_VARIANTS`: the paper's full model and its
    ablations, all in the paper's form; the models' own seed)."""
    df = _idm_runs(df)
    return df[(df["views"] == RIG_VIEWS) & df["variant"].isin(ABLATION_VARIANTS)]


def k_rows(df: pd.DataFrame) -> pd.DataFrame:
    """Per-image rows of the K sweep (6 views, the full model and the ``k*`` variants)."""
    df = _idm_runs(df)
    v = df["variant"].astype(str)
    return df[(df["views"] == RIG_VIEWS) & (df["method"] == "F-RNG") & ((v == "full") | v.str.match(r"^k[0-9.]+$"))]


def views_rows(df: pd.DataFrame) -> pd.DataFrame:
    """Per-image rows of the #views sweep (the full model at every view count)."""
    df = _idm_runs(df)
    return df[df["variant"] == "full"]


# -- tables --------------------------------------------------------------------------------------------------


def headline_means(df: pd.DataFrame) -> dict[str, pd.DataFrame]:
    """{run: its per-image rows averaged over training seeds} of the :data:`HEADLINE_RUNS` and the backbone."""
    return {run: seed_mean(df, run) for run in [*(r for r, _ in HEADLINE_RUNS), BACKBONE]}


def _vs_backbone_rows(df: pd.DataFrame, means: dict[str, pd.DataFrame], pick, key: dict) -> list[dict]:
    """The F-RNG, F-RNG+ and backbone rows of one group of a vs-backbone table: ``key`` (the group's column and
    value), method, n and the mean metrics of ``pick`` of each run's seed means (:func:`headline_means`); the F-RNG
    rows add the paired difference to the backbone (:func:`diff_to`) and the per-seed columns over the same ``pick``
    of ``df``. Runs without rows (F-RNG+ not trained) are left out."""
    rows = []
    for run, method in [*HEADLINE_RUNS, (BACKBONE, BACKBONE)]:
        sub = pick(means[run])
        if not len(sub):
            continue
        row = {
            **key,
            "method": METHOD_LABELS[method],
            **image_means(sub),
        }
        if run != BACKBONE:
            frng_parts, bb_parts = [*seed_parts(df, run, pick).values()], [*seed_parts(df, BACKBONE, pick).values()]
            row |= diff_to(frng_parts, bb_parts, T.VS_BACKBONE_DIFF_METRICS)
            row |= seed_columns(df, run, BACKBONE, pick)
        rows.append(row)
    return rows


def vs_backbone_table(df: pd.DataFrame, timings: list[dict]) -> tuple[pd.DataFrame, pd.DataFrame]:
    """Per dataset (then ``all``): F-RNG (``full``, averaged over its training seeds) and the backbone, with F-RNG's
    paired difference to the backbone and the seed columns."""
    means = headline_means(df)
    rows = []
    datasets = sorted(set(means["full"]["dataset"]) | set(means[BACKBONE]["dataset"])) + ["all"]
    for ds in datasets:
        pick = (lambda d: d) if ds == "all" else (lambda d, ds=ds: d[d["dataset"] == ds])
        rows += _vs_backbone_rows(df, means, pick, {"dataset": ds})
    out = pd.DataFrame(rows)
    timed = [m for _, m in HEADLINE_RUNS if timings and all(m in t for t in timings)] + [BACKBONE]
    ms = {METHOD_LABELS[m]: float(np.mean([t[m]["relight_ms_per_image"] for t in timings])) for m in timed}
    main, footer = T.vs_backbone(out, ms)
    extra = [c for c in ["n", *T.diff_columns(T.VS_BACKBONE_DIFF_METRICS), *T.SEED_COLUMNS] if c in out.columns]
    return pd.concat([main, out[extra]], axis=1), footer


def ablation_table(df: pd.DataFrame) -> pd.DataFrame:
    """Each variant of :data:`ABLATION_VARIANTS` averaged over its training seeds; differences to the full model."""
    present = [v for v in ABLATION_VARIANTS if len(ablation_rows(df)[lambda d, v=v: d["variant"] == v])]
    rows = []
    for v in present:
        sub = seed_mean(df, v)
        sub = sub[sub["views"] == RIG_VIEWS]
        row = {
            "variant": VARIANT_LABELS[v],
            **image_means(sub),
        }
        if v != "full":
            row |= diff_to([*seed_parts(df, v, _at_rig).values()], [*seed_parts(df, "full", _at_rig).values()])
        row |= seed_columns(df, v, None if v == "full" else "full")
        rows.append(row)
    return _ordered(pd.DataFrame(rows), "ablation")


ALL_ADDITIONS = "all of them (F-RNG+ over the paper form)"


def additions_table(df: pd.DataFrame) -> pd.DataFrame:
    """What the project's additions are worth (issue 85; :data:`frng.plan.variants.ADDITIONS`): F-RNG+ over the paper
    form (every addition at once: ``plus`` minus ``full``), then F-RNG+ over F-RNG+ without each addition the config
    trained (``plus`` minus ``plus-no-{addition}``: what that one adds beside the others). Rows: the addition, the
    paper section it departs from, the reference model's means (the paper form, or F-RNG+ without it), the paired
    difference (F-RNG+ minus that reference) averaged over training seeds. Empty without F-RNG+."""
    if not len(seed_parts(df, PLUS, _at_rig)):
        return _ordered(pd.DataFrame(columns=["addition"]), "additions")
    refs = [("full", ALL_ADDITIONS, "the paper's F-RNG (every section)")]
    refs += [(v, key, ADDITIONS[key].departs_from) for v, key in LEAVE_OUT_VARIANTS.items()]
    rows = []
    for ref, name, section in refs:
        ref_parts = [*seed_parts(df, ref, _at_rig).values()]
        if not ref_parts:
            continue
        sub = seed_mean(df, ref)
        rows.append(
            {"addition": name, "departs_from": section, **image_means(sub[sub["views"] == RIG_VIEWS])}
            | diff_to([*seed_parts(df, PLUS, _at_rig).values()], ref_parts)
            | seed_columns(df, PLUS, ref)
        )
    return _ordered(pd.DataFrame(rows), "additions")


def _at_rig(d: pd.DataFrame) -> pd.DataFrame:
    return d[d["views"] == RIG_VIEWS]


def _ordered(out: pd.DataFrame, table: str) -> pd.DataFrame:
    """The table's own columns first, then n, the difference and the seed columns present."""
    main = list(T.TABLE_COLUMNS[table])
    rest = [c for c in ["n", *T.diff_columns(T.VS_BACKBONE_DIFF_METRICS), *T.SEED_COLUMNS]]
    rest = [c for c in rest if c in out.columns and c not in main]
    return out.reindex(columns=main + rest).reset_index(drop=True)


def _sweep_table(rows: pd.DataFrame, key: str, ref_value, table: str, rename: str | None = None) -> pd.DataFrame:
    ref = rows[rows[key] == ref_value]
    out = []
    for value, sub in sorted(rows.groupby(key), key=lambda kv: kv[0]):
        row = {
            rename or key: value,
            **image_means(sub),
        }
        if value != ref_value and len(ref):
            row |= diff_to(sub, ref)
        out.append(row)
    return _ordered(pd.DataFrame(out), table)


def views_table(df: pd.DataFrame) -> pd.DataFrame:
    """Per input-view count; differences to the rig's 6 views."""
    return _sweep_table(views_rows(df), "views", RIG_VIEWS, "views")


def k_table(df: pd.DataFrame) -> pd.DataFrame:
    """Per K; differences to the full model's K (the ``full`` run's)."""
    rows = k_rows(df)
    full_k = rows.loc[rows["run"] == "full", "k"]
    ref = float(full_k.iloc[0]) if len(full_k) else np.nan
    return _sweep_table(rows, "k", ref, "k", rename="k_percent")


def k_against_paper_k(df: pd.DataFrame, paper_k: float = 2.0) -> dict[float, dict]:
    """{K: the paired-difference columns of K minus K = ``paper_k`` %} over the K sweep's rows (empty without that
    K): what the claims table judges the paper's choice of K = 2 % by."""
    rows = k_rows(df)
    ref = rows[rows["k"].astype(float) == paper_k]
    if not len(ref):
        return {}
    return {float(k): diff_to(sub, ref) for k, sub in rows.groupby("k") if float(k) != paper_k}


def claims(df: pd.DataFrame, timings: list[dict]) -> pd.DataFrame:
    """The claims table (:mod:`frng.report.claims`) of these per-image rows and timings: every claim under the rows'
    protocol, then the PSNR claims again under the other protocol (the rows' ``psnr_{protocol}`` column, where the
    per-image CSV has it): alignment absorbs the colour errors the paper attributes to w/o IDM and w/o L_ind."""
    from frng.report.claims import claims_table

    labels = {**{v: VARIANT_LABELS[v] for v in ABLATION_VARIANTS if v != "full"}, "full": METHOD_LABELS["F-RNG"]}
    t = timing_table(timings)
    frng_row = t[t["method"] == METHOD_LABELS["F-RNG"]]
    speedup = float(frng_row["speedup"].iloc[0]) if len(frng_row) else float("nan")
    protocol = str(df["protocol"].iloc[0]) if "protocol" in df and len(df) else M.DEFAULT_PROTOCOL
    out = []
    for p in [protocol, *(q for q in M.PROTOCOLS if q != protocol)]:
        col = f"psnr_{p}"
        if p != protocol and (col not in df or df[col].isna().all()):
            continue  # per-image rows written before both protocols were scored
        d = df if p == protocol else df.assign(psnr=df[col])
        vs, _ = vs_backbone_table(d, timings)
        out.append(claims_table(vs, ablation_table(d), k_against_paper_k(d), speedup, labels, p, p != protocol))
    return pd.concat(out, ignore_index=True)


def lambertian_table(df: pd.DataFrame) -> pd.DataFrame:
    """Per material class (then ``all``): F-RNG+ (``plus``: the paper's form has no Lambertian base) and its
    Lambertian base alone (``plus-base``), with the base's paired difference to F-RNG+. The models' own seed."""
    full, base = df[df["run"] == PLUS], df[df["run"] == BASE_RUN]
    if not len(base):
        return pd.DataFrame(columns=list(T.TABLE_COLUMNS["lambertian"]))
    rows = []
    for ds in sorted(set(full["dataset"])) + ["all"]:
        f = full if ds == "all" else full[full["dataset"] == ds]
        b = base if ds == "all" else base[base["dataset"] == ds]
        for label, sub in ((METHOD_LABELS[PLUS_METHOD], f), (BASE_LABEL, b)):
            row = {
                "dataset": ds,
                "method": label,
                **image_means(sub),
                "scale_log2": M.scale_log2(sub),
                "brightness_log2": M.brightness_log2(sub),
            }
            if label == BASE_LABEL:
                row |= diff_to(sub, f)
            rows.append(row)
    return _ordered(pd.DataFrame(rows), "lambertian")


# -- per light family ------------------------------------------------------------------------------------------

LIGHT_FAMILY = "light_family"
OTHER_FAMILY = "other"  # a light the plan does not know (not one of its maps)


def with_families(df: pd.DataFrame | None, families: Mapping[str, str]) -> pd.DataFrame | None:
    """``df`` with a ``light_family`` column: the family of each row's ``light`` (``families``: map name -> family,
    from the dataset plan, :meth:`frng.plan.catalog.Catalog.light_families`; lights it lacks are
    :data:`OTHER_FAMILY`). Frames without a ``light`` column come back unchanged."""
    if df is None or "light" not in df.columns:
        return df
    out = df.copy()
    out[LIGHT_FAMILY] = out["light"].astype(str).map(dict(families)).fillna(OTHER_FAMILY)
    return out


def family_order(df: pd.DataFrame) -> list[str]:
    """The light families present in ``df`` (sky, hdri, studio, user, then other)."""
    from frng.plan.catalog import FAMILIES

    present = set(df[LIGHT_FAMILY]) if LIGHT_FAMILY in df.columns else set()
    return [f for f in (*FAMILIES, OTHER_FAMILY) if f in present]


def _of_family(d: pd.DataFrame | None, family: str) -> pd.DataFrame | None:
    if d is None or LIGHT_FAMILY not in d.columns:
        return d if d is None else d.iloc[:0]
    return d[d[LIGHT_FAMILY] == family]


def vs_backbone_by_light(df: pd.DataFrame) -> pd.DataFrame:
    """:func:`vs_backbone_table` per family of the target light instead of per dataset (``df`` with
    :func:`with_families`' column): F-RNG (averaged over its training seeds) and the backbone, F-RNG's paired
    difference to the backbone over the same images with its object (and seed) bootstrap interval, the seed
    columns. No ``all`` rows: the ``vs_backbone`` table's."""
    means = headline_means(df)
    rows = []
    for fam in family_order(df):
        pick = lambda d, fam=fam: _of_family(d, fam)  # noqa: E731
        rows += _vs_backbone_rows(df, means, pick, {LIGHT_FAMILY: fam})
    return _ordered(pd.DataFrame(rows), "vs_backbone_by_light")


OBJECT_SOURCE = "object_source"


def vs_backbone_by_source(df: pd.DataFrame, sources: Mapping[str, str]) -> pd.DataFrame:
    """:func:`vs_backbone_table` per source of the test object (``sources``: object id -> source, from the dataset
    plan, :meth:`frng.plan.catalog.Catalog.object_sources`; objects it lacks are ``other``), sources in name order:
    whether F-RNG's lead holds on real assets (LIBERO, Objaverse, users') as on generated shapes. The differences and
    their intervals are computed within each source. No ``all`` rows: the ``vs_backbone`` table's."""
    df = df.assign(**{OBJECT_SOURCE: df["object"].astype(str).map(dict(sources)).fillna("other")})
    means = headline_means(df)
    rows = []
    for src in sorted(set(means["full"].get(OBJECT_SOURCE, [])) | set(means[BACKBONE].get(OBJECT_SOURCE, []))):
        pick = lambda d, src=src: d[d[OBJECT_SOURCE] == src]  # noqa: E731
        rows += _vs_backbone_rows(df, means, pick, {OBJECT_SOURCE: src})
    return _ordered(pd.DataFrame(rows, columns=None if rows else [OBJECT_SOURCE]), "vs_backbone_by_source")


def ablation_by_light(df: pd.DataFrame) -> pd.DataFrame:
    """:func:`ablation_table` for each family of the target light (rows: family, then variant)."""
    parts = []
    for fam in family_order(df):
        t = ablation_table(_of_family(df, fam))
        if len(t):
            parts.append(t.assign(**{LIGHT_FAMILY: fam}))
    out = pd.concat(parts, ignore_index=True) if parts else pd.DataFrame(columns=[LIGHT_FAMILY])
    return _ordered(out, "ablation_by_light")


def ladder_by_light(df: pd.DataFrame, prior: pd.DataFrame, cross: pd.DataFrame | None = None) -> pd.DataFrame:
    """:func:`ladder_table` for each family of the light (rows: family, then step; the light-sensitivity rows
    ``s*`` included, by the family of the light rendered). Row c's light is the input light (the held-out input
    views): it is grouped under the input light's family."""
    parts = []
    for fam in family_order(df):
        t = ladder_table(_of_family(df, fam), _of_family(prior, fam), _of_family(cross, fam))
        if len(t):
            parts.append(t.assign(**{LIGHT_FAMILY: fam}))
    out = pd.concat(parts, ignore_index=True) if parts else pd.DataFrame(columns=[LIGHT_FAMILY])
    main = list(T.TABLE_COLUMNS["ladder_by_light"])
    rest = [c for c in ["vs", *T.diff_columns()] if c in out.columns]
    return out.reindex(columns=main + rest).reset_index(drop=True)


def timing_table(timings: list[dict]) -> pd.DataFrame:
    rows = []
    for m in [m for _, m in HEADLINE_RUNS if all(m in t for t in timings)] + [BACKBONE]:
        rows.append(
            {
                "method": METHOD_LABELS[m],
                "reconstruction_s": float(np.mean([t[m]["reconstruction_s"] for t in timings])),
                "relight_ms_per_image": float(np.mean([t[m]["relight_ms_per_image"] for t in timings])),
                "resolution": int(timings[0]["resolution"]),
                "spp": timings[0]["spp"] if m != BACKBONE else np.nan,
            }
        )
    return T.timing(pd.DataFrame(rows), reference=METHOD_LABELS[BACKBONE])


def write_tables(
    tier: str,
    background: Sequence[float],
    per_image_csv: Path,
    timing_files: list[Path],
    out_dir: Path,
    prior_csv: Path,
    cross_csv: Path | None = None,
    families: Mapping[str, str] | None = None,
    sources: Mapping[str, str] | None = None,
    noise_csv: Path | None = None,
) -> dict[str, dict]:
    """Write the tables (see the module docstring). Returns {table: {"csv"|"md"|"tex": path}}. ``tier`` and
    ``background`` (the config's ``tier`` and ``eval.background``) go into the captions. ``families``: map name ->
    light family (the dataset plan's, :meth:`frng.plan.catalog.Catalog.light_families`); without it the per-family
    tables (``*_by_light``) are not written; ``sources``: object id -> source (the plan's,
    :meth:`frng.plan.catalog.Catalog.object_sources`), without it ``vs_backbone_by_source`` is not written;
    ``noise_csv``: the targets' noise floor (``frng noise-floor``: rows in the priors' layout), the ladders' step 0."""
    df = M.read_csv(per_image_csv)
    missing = [
        c
        for c in ("dataset", "object", "run", "method", "variant", "views", "k", "psnr", "ssim", "lpips", "protocol")
        if c not in df.columns
    ]
    if missing:
        raise KeyError(f"{per_image_csv}: missing columns {missing}")
    cross = M.read_csv(cross_csv) if cross_csv is not None else None
    timings = [io.read_json(p) for p in timing_files]
    if not timings:
        raise ValueError("frng tables: no relighting timing files given")
    device = sorted({t["device"] for t in timings})
    seeds = sorted({r for r in df["run"].astype(str) if base_run(r) == "full"})
    seed_note = (
        f" F-RNG rows: mean over {len(seeds)} training seeds ({', '.join(seeds)}); seed spread = max - min over seeds."
        if len(seeds) > 1
        else ""
    )
    out = {}

    table = functools.partial(_captioned, out_dir, tier, background)

    rows, footer = vs_backbone_table(df, timings)
    out["vs_backbone"] = table(
        "vs_backbone",
        rows,
        "Relighting quality under the paper's task (the input views' light unknown to every method): F-RNG (the "
        "paper's form), F-RNG+ (the project's additions on) and the backbone they build on (datasets = material "
        "classes). PSNR interior = "
        f"the same PSNR over the foreground without its {M.RIM_PX} px silhouette rim (relighting, not the outline)."
        + seed_note,
        df[df["run"].isin(["full", PLUS, BACKBONE])],
        footer=footer,
        best_within=["dataset"],
    )
    out["ablation"] = table(
        "ablation",
        ablation_table(df),
        "Ablation of F-RNG's components (differences: variant minus the full model)."
        + seed_note.replace("F-RNG rows", "Every row"),
        ablation_rows(df),
    )
    out["additions"] = table(
        "additions",
        additions_table(df),
        "What the project's additions are worth under the paper's task (frng.plan.variants.ADDITIONS; "
        "docs/model-and-training.md): each row's means are its reference model's (the paper's form for 'all of "
        "them', F-RNG+ without that addition for the others); Δ = F-RNG+ minus that reference."
        + seed_note.replace("F-RNG rows", "Every row"),
        df[df["variant"].isin([PLUS, "full", *LEAVE_OUT_VARIANTS]) & (df["views"] == RIG_VIEWS)],
    )
    out["views"] = table(
        "views",
        views_table(df),
        "Number of input views (the same trained full model; differences to 6 views).",
        views_rows(df),
    )
    out["k"] = table(
        "k",
        k_table(df),
        "Top-K salient patches (K in % of a view's patches; differences to the full model's K).",
        k_rows(df),
    )
    prior = pd.read_csv(prior_csv)
    if noise_csv is not None:
        prior = pd.concat([prior, pd.read_csv(noise_csv)], ignore_index=True)
    steps, sensitivity = split_ladder(ladder_table(df, prior, cross))
    out["ladder"] = _write(
        out_dir,
        "ladder",
        steps,
        footer=sensitivity,
        footer_best=False,
        caption=(
            f"Quality ladder: where the dB go. Aligned protocol on the held-out relighting images (row c: the "
            f"held-out input-light views; row 0: the ground truth itself against a high-spp render of the same "
            f"views, the first test object of each material class, render.noise_floor; row 0r: that reference's "
            f"two renders against each other); PSNR interior = the same PSNR over the foreground without its "
            f"{M.RIM_PX} px silhouette rim (where the geometry's outline decides the error); silhouette IoU = "
            f"intersection over union of the render's silhouette (alpha > 0.5) and the ground truth's; depth error = "
            f"mean |distance - G-buffer distance| of the geometry's per-pixel Gaussians along the input pixels' rays "
            f"(world units, objects in the unit sphere; F-RNG's coarse geometry is the backbone's); "
            f"scale_log2 = median over images and channels of |log2| of the "
            f"per-channel least-squares scale the protocol applied; brightness_log2 = the same of the ratio of "
            f"means (ground truth over prediction). Row g: F-RNG rendered with its decoder's closed-form Lambertian "
            f"base alone. Rows s: each method's render for one test light scored against the ground truth of another "
            f"test light (same object and view); their Δ = right light minus that wrong light (ground truth: "
            f"itself vs the other light's). {DIFF_NOTE} The models' own training seed. Tier {tier}."
        ),
    )
    out["lambertian"] = table(
        "lambertian",
        lambertian_table(df),
        "F-RNG+ and its decoder's closed-form Lambertian base alone (residual, attenuation and "
        "specular base dropped), per material class; differences: base minus F-RNG+.",
        df[df["run"].isin([PLUS, BASE_RUN])],
    )
    out["ladder_by_class"] = _write(
        out_dir,
        "ladder_by_class",
        ladder_by_class(df, prior, cross),
        best_within=["dataset"],
        caption=(
            "Quality ladder per material class (the ladder table's steps and light-sensitivity rows s, each "
            f"class's objects only; PSNR interior: PSNR over the foreground without its {M.RIM_PX} px silhouette "
            "rim; silhouette IoU: of the render's alpha > 0.5 and the ground truth's; depth error: the mean "
            "|ray distance - G-buffer distance| of the geometry's per-pixel Gaussians at the input views' "
            f"pixels, world units, per object). {DIFF_NOTE} The models' own training seed. Tier {tier}."
        ),
    )
    if families is not None:
        out |= _write_family_tables(tier, background, df, prior, cross, families, out_dir, seed_note)
    if sources is not None:
        out["vs_backbone_by_source"] = table(
            "vs_backbone_by_source",
            vs_backbone_by_source(df, sources),
            "Relighting quality per object source: F-RNG vs the backbone (the dataset plan's object sources: "
            "generated shapes: procedural, primitives, pybullet; real assets: libero = LIBERO's modelled objects, "
            "objaverse, user); the differences and their "
            "intervals are computed within each source." + seed_note,
            df[df["run"].isin(["full", PLUS, BACKBONE])],
            best_within=[OBJECT_SOURCE],
        )
    out["claims"] = _write(
        out_dir,
        "claims",
        claims(df, timings),
        caption=(
            "The paper's claims (Tables 1 and 4, the K table; Objaverse, its numbers) beside this tier's: the "
            "measured difference (row minus its reference: F-RNG minus the backbone, a variant minus the full "
            "model, K minus K = 2 %) with its 95 % paired bootstrap interval over test objects (and training "
            "seeds where there are several); speed-up: the backbone's relighting time per image over F-RNG's. "
            "Verdict on the sign the paper claims: held / not held (the interval on the other side of 0) / not "
            "resolved (it contains 0) / not measured. F-RNG = the paper's form; every method is told no input "
            "light. Each claim under the tier's protocol, the PSNR claims again under the other (column protocol: "
            "aligned = per-channel scale, foreground; plain = no scale, whole image). Where a claim is not held, "
            "why is measured, not tuned away: docs/studies/2026-12-05-why-the-paper-form-does-not-relight.md "
            "(at the default tier the paper's form learns no light dependence, so its ablation rows compare models "
            f"that do not relight). Tier {tier}."
        ),
    )
    t = timing_table(timings)
    out["timing"] = _write(
        out_dir,
        "timing",
        t,
        caption=(
            f"Reconstruction and relighting time per image, measured side by side in the same job on "
            f"{', '.join(device)} at {int(t['resolution'].iloc[0])} px, mean over {len(timings)} test "
            f"object(s); F-RNG renders with {t['spp'].iloc[0]:.0f} light samples per pixel, the backbone "
            f"runs one full denoising pass per light. Tier {tier}."
        ),
    )
    return out


def _write_family_tables(tier, background, df, prior, cross, families, out_dir: Path, seed_note: str) -> dict:
    """The ``*_by_light`` tables: vs_backbone, ablation and ladder per family of the target light."""
    df, prior, cross = (with_families(d, families) for d in (df, prior, cross))
    fams = ", ".join(family_order(df))
    note = (
        f" Per family of the target light ({fams}: the dataset plan's light families, frng.plan.catalog "
        "FAMILIES); the differences and their intervals are computed within each family."
    )
    out = {}

    table = functools.partial(_captioned, out_dir, tier, background)

    out["vs_backbone_by_light"] = table(
        "vs_backbone_by_light",
        vs_backbone_by_light(df),
        "Relighting quality per light family: F-RNG vs the backbone." + note + seed_note,
        df[df["run"].isin(["full", PLUS, BACKBONE])],
        best_within=[LIGHT_FAMILY],
    )
    out["ablation_by_light"] = table(
        "ablation_by_light",
        ablation_by_light(df),
        "Ablation per light family (differences: variant minus the full model)."
        + note
        + seed_note.replace("F-RNG rows", "Every row"),
        ablation_rows(df),
        best_within=[LIGHT_FAMILY],
    )
    out["ladder_by_light"] = _write(
        out_dir,
        "ladder_by_light",
        ladder_by_light(df, prior, cross),
        best_within=[LIGHT_FAMILY],
        caption=(
            "Quality ladder per light family (the ladder table's steps and light-sensitivity rows s, each family's "
            f"images only; row c: the input light's family; PSNR interior: PSNR over the foreground without its "
            f"{M.RIM_PX} px silhouette rim; silhouette IoU: of the render's alpha > 0.5 and the ground truth's).{note} {DIFF_NOTE} The models' own training seed. "
            f"Tier {tier}."
        ),
    )
    return out
