"""Write result tables as CSV + Markdown + LaTeX (booktabs), with the best value per metric column marked.

Marking follows the paper: in LaTeX the best cell is ``\\cellcolor{tabfirst}{...}`` (and, with ``second=True``,
the runner-up ``\\cellcolor{tabsecond}{...}``), colours defined as in the paper::

    \\usepackage{booktabs}  \\usepackage[table]{xcolor}
    \\definecolor{tabfirst}{rgb}{1, 0.7, 0.7}  \\definecolor{tabsecond}{rgb}{1, 0.85, 0.7}

(written as a comment at the top of every .tex file). In Markdown the best is **bold** (the second *italic*).
CSV holds the unrounded values, no marking.

Which columns are metrics and their direction (:func:`direction`): ``psnr``, ``ssim`` and ``speedup``-like
columns are higher-is-better; ``lpips`` and times (``*_s``, ``*_ms``, ``*_ms_per_image``, ``time``) are
lower-is-better; anything else (``views``, ``k_percent``, ``resolution``, ``spp``, ``n``, labels) is not marked.
Best values are compared after rounding to the displayed precision, so ties are all marked; with
``best_within`` the best is found within each group of rows (e.g. per dataset when comparing methods).

Paired differences (:data:`DIFF_METRICS`): a table row may carry ``d{metric}``, ``d{metric}_lo``, ``d{metric}_hi``
(the row minus its reference row, mean over the same images, and its 95% bootstrap interval over test objects:
:mod:`frng.report.stats`) for psnr, ssim and lpips, plus ``better`` / ``objects`` (objects whose mean PSNR is
above the reference's / how many objects) and the training-seed columns ``seeds``, ``seed_spread_psnr``,
``seed_spread_dpsnr``. CSV keeps every column; Markdown and LaTeX show one cell per difference, e.g.
``+0.34 [0.25, 0.58]``, and ``better`` as ``16/16``. Differences are never best-marked.

The five tables of issue 6 and their columns (:data:`TABLE_COLUMNS`):
``vs_backbone`` (dataset, method, psnr, ssim, lpips, plus a relighting-time footer row per method: see
:func:`vs_backbone`), ``ablation`` (variant, ...), ``views`` (views, ...), ``k`` (k_percent, ...),
``timing`` (method, reconstruction_s, relight_ms_per_image, resolution, spp; plus ``speedup`` from
:func:`timing`).
"""

from __future__ import annotations

import math
import os
from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np
import pandas as pd

from frng.io import atomic_path

# the quality ladder's columns (frng.report.ladder.ladder_table); its per-light-family table adds the family
LADDER_COLUMNS = (
    "step",
    "what",
    "n",
    "psnr",
    "psnr_interior",
    "silhouette_iou",
    "depth_error",
    "ssim",
    "lpips",
    "scale_log2",
    "brightness_log2",
)

TABLE_COLUMNS: dict[str, tuple[str, ...]] = {
    "vs_backbone": ("dataset", "method", "psnr", "psnr_interior", "ssim", "lpips"),
    "ablation": ("variant", "psnr", "ssim", "lpips"),
    # F-RNG+ over the paper form, and over F-RNG+ without each addition (frng/plan/variants.py ADDITIONS)
    "additions": ("addition", "departs_from", "psnr", "ssim", "lpips"),
    "views": ("views", "psnr", "ssim", "lpips"),
    "k": ("k_percent", "psnr", "ssim", "lpips"),
    "timing": ("method", "reconstruction_s", "relight_ms_per_image", "resolution", "spp"),
    "ladder": LADDER_COLUMNS,
    "lambertian": ("dataset", "method", "n", "psnr", "ssim", "lpips", "scale_log2", "brightness_log2"),
    # per family of the target light (sky / hdri / studio; frng/report/paper_tables.py)
    "vs_backbone_by_light": ("light_family", "method", "psnr", "psnr_interior", "ssim", "lpips"),
    # per source of the test object (procedural shapes, LIBERO's modelled assets, Objaverse, the user's)
    "vs_backbone_by_source": ("object_source", "method", "psnr", "psnr_interior", "ssim", "lpips"),
    "ablation_by_light": ("light_family", "variant", "psnr", "ssim", "lpips"),
    "ladder_by_light": ("light_family", *(c for c in LADDER_COLUMNS if c != "depth_error")),  # depth: per object
    # per material class of the test object (the per-image ``dataset``): its geometry's IoU and depth error too
    "ladder_by_class": ("dataset", *LADDER_COLUMNS),
    # the paper's claims beside this tier's measurements (frng/report/claims.py)
    "claims": ("claim", "source", "protocol", "paper", "measured", "measured_lo", "measured_hi", "objects", "verdict"),
}

DIFF_METRICS = ("psnr", "ssim", "lpips")
# the vs-backbone tables' differences also cover PSNR inside the silhouette (without its 2 px rim: where the outline,
# not the relighting, decides the error), so a gain at the silhouette is not read as better relighting
VS_BACKBONE_DIFF_METRICS = ("psnr", "psnr_interior", "ssim", "lpips")


def diff_columns(metrics: Sequence[str] = DIFF_METRICS) -> list[str]:
    """``d{m}, d{m}_lo, d{m}_hi`` per metric, then ``better``, ``objects``: the paired-difference columns."""
    return [f"d{m}{s}" for m in metrics for s in ("", "_lo", "_hi")] + ["better", "objects"]


SEED_COLUMNS = ("seeds", "seed_spread_psnr", "seed_spread_dpsnr")

# Displayed decimals per column (others: 3 for floats, none for integers).
DECIMALS: dict[str, int] = {
    "psnr": 2,
    "psnr_interior": 2,
    "silhouette_iou": 3,
    "depth_error": 3,
    "ssim": 3,
    "lpips": 3,
    "reconstruction_s": 2,
    "relight_ms_per_image": 1,
    "speedup": 1,
    "k_percent": 0,
    "dpsnr": 2,
    "dpsnr_interior": 2,
    "dssim": 3,
    "dlpips": 4,
    "seed_spread_psnr": 2,
    "seed_spread_dpsnr": 2,
    "scale_log2": 2,
    "brightness_log2": 2,
}

HEADERS: dict[str, str] = {
    "psnr": "PSNR",
    "psnr_interior": "PSNR interior",
    "silhouette_iou": "silhouette IoU",
    "depth_error": "depth error",
    "ssim": "SSIM",
    "lpips": "LPIPS",
    "dataset": "Dataset",
    "light_family": "Light family",
    "object_source": "Object source",
    "method": "Method",
    "variant": "Variant",
    "addition": "Addition",
    "departs_from": "Departs from (paper)",
    "views": "Input views",
    "k_percent": "K (%)",
    "reconstruction_s": "Reconstruction (s)",
    "relight_ms_per_image": "Relighting (ms/image)",
    "resolution": "Resolution",
    "spp": "spp",
    "speedup": "Speed-up",
    "n": "n",
    "step": "Step",
    "what": "What",
    "scale_log2": "median |log2 scale|",
    "brightness_log2": "median |log2 mean ratio|",
    "dpsnr": "ΔPSNR [95% CI]",
    "dpsnr_interior": "ΔPSNR interior [95% CI]",
    "dssim": "ΔSSIM [95% CI]",
    "dlpips": "ΔLPIPS [95% CI]",
    "better": "objects higher PSNR",
    "seeds": "seeds",
    "seed_spread_psnr": "seed spread PSNR",
    "seed_spread_dpsnr": "seed spread ΔPSNR",
    "vs": "Δ vs",
    "finding": "Finding",
}
TEX_HEADERS: dict[str, str] = {  # LaTeX source, not escaped
    "dpsnr": "$\\Delta$PSNR [95\\% CI]",
    "dpsnr_interior": "$\\Delta$PSNR interior [95\\% CI]",
    "dssim": "$\\Delta$SSIM [95\\% CI]",
    "dlpips": "$\\Delta$LPIPS [95\\% CI]",
    "seed_spread_dpsnr": "seed spread $\\Delta$PSNR",
    "vs": "$\\Delta$ vs",
}

LATEX_PREAMBLE_NOTE = (
    "% Needs \\usepackage{booktabs} and \\usepackage[table]{xcolor} with\n"
    "% \\definecolor{tabfirst}{rgb}{1, 0.7, 0.7} \\definecolor{tabsecond}{rgb}{1, 0.85, 0.7}\n"
)


def direction(column: str) -> str | None:
    """ "max", "min" or None (not a metric column) for a column name."""
    c = column.lower()
    if c in ("psnr", "ssim", "silhouette_iou") or c.startswith(("psnr_", "ssim_")) or "speedup" in c:
        return "max"
    if (
        c in ("lpips", "depth_error")
        or c.startswith("lpips_")
        or c.endswith(("_s", "_ms", "_ms_per_image"))
        or "time" in c
    ):
        return "min"
    return None


def _decimals(df: pd.DataFrame, col: str, decimals: Mapping[str, int]) -> int | None:
    if col in decimals:
        return decimals[col]
    if col in DECIMALS:
        return DECIMALS[col]
    if pd.api.types.is_integer_dtype(df[col]):
        return None
    if pd.api.types.is_float_dtype(df[col]):
        vals = df[col].dropna()
        if len(vals) and np.all(np.isfinite(vals)) and np.all(vals == np.round(vals)):
            return 0  # integral floats (e.g. an int column with a blank footer cell)
        return 3
    return None


def _fmt(value, ndp: int | None) -> str:
    """Display string of one cell: blank for missing, fixed decimals for floats, str() otherwise."""
    if value is None or (isinstance(value, (float, np.floating)) and math.isnan(value)):
        return ""
    if isinstance(value, (float, np.floating)):
        if math.isinf(value):
            return "inf" if value > 0 else "-inf"
        return f"{value:.{3 if ndp is None else ndp}f}"
    return str(value)


def _present(value) -> bool:
    return not (value is None or (isinstance(value, (float, np.floating)) and math.isnan(value)))


def _ranks(df: pd.DataFrame, formatted: pd.DataFrame, best_within: Sequence[str], second: bool) -> pd.DataFrame:
    """(rows, cols) frame of 0 (unmarked), 1 (best) or 2 (second best), from the displayed values."""
    rank = pd.DataFrame(0, index=df.index, columns=df.columns)
    groups = (
        [df.index] if not best_within else [idx for _, idx in df.groupby(list(best_within), sort=False).groups.items()]
    )
    for col in df.columns:
        d = direction(col)
        if d is None or not pd.api.types.is_numeric_dtype(df[col]):
            continue
        for idx in groups:
            shown = pd.to_numeric(formatted.loc[idx, col], errors="coerce").dropna()
            shown = shown[np.isfinite(shown)]
            if len(shown) < 2:
                continue
            distinct = sorted(shown.unique(), reverse=(d == "max"))
            rank.loc[shown.index[shown == distinct[0]], col] = 1
            if second and len(distinct) > 1:
                rank.loc[shown.index[shown == distinct[1]], col] = 2
    return rank


_TEX_ESCAPES = {
    "\\": "\\textbackslash{}",
    "&": "\\&",
    "%": "\\%",
    "_": "\\_",
    "#": "\\#",
    "$": "\\$",
    "{": "\\{",
    "}": "\\}",
    "~": "\\textasciitilde{}",
    "^": "\\textasciicircum{}",
}


def _escape_tex(s: str) -> str:
    return "".join(_TEX_ESCAPES.get(ch, ch) for ch in s)


def _header(col: str, fmt: str) -> str:
    if fmt == "tex" and col in TEX_HEADERS:
        return TEX_HEADERS[col]
    name = HEADERS.get(col, col)
    arrow = {"max": ("$\\uparrow$", " ↑"), "min": ("$\\downarrow$", " ↓")}.get(direction(col))
    if fmt == "tex":
        return _escape_tex(name) + (arrow[0] if arrow else "")
    return name.replace("|", "\\|") + (arrow[1] if arrow else "")  # a bare | would end the Markdown cell


def render(
    df: pd.DataFrame,
    footer: pd.DataFrame | None = None,
    best_within: Sequence[str] = (),
    second: bool = False,
    decimals: Mapping[str, int] | None = None,
    caption: str | None = None,
    label: str | None = None,
    footer_best: bool = True,
) -> tuple[str, str]:
    """Render (markdown, latex) strings. See :func:`write_table` for the arguments."""
    decimals = dict(decimals or {})
    blocks = [df.reset_index(drop=True)]
    if footer is not None and len(footer):
        blocks.append(footer.reindex(columns=df.columns.union(footer.columns, sort=False)).reset_index(drop=True))
    cols = list(blocks[-1].columns) if len(blocks) > 1 else list(df.columns)
    blocks = [b.reindex(columns=cols) for b in blocks]
    whole = pd.concat(blocks, ignore_index=True)
    ndp = {c: _decimals(whole, c, decimals) for c in cols}
    # a difference with its interval is one displayed cell; so is better/objects
    intervals = [c for c in cols if f"{c}_lo" in cols and f"{c}_hi" in cols]
    hidden = {f"{c}{s}" for c in intervals for s in ("_lo", "_hi")}
    if "better" in cols and "objects" in cols:
        hidden.add("objects")
    cols = [c for c in cols if c not in hidden]

    def cell(block: pd.DataFrame, c: str, i) -> str:
        v = block.at[i, c]
        if c in intervals:
            lo, hi = block.at[i, f"{c}_lo"], block.at[i, f"{c}_hi"]
            if not _present(v):
                return ""
            nd = 3 if ndp[c] is None else ndp[c]
            if not (_present(lo) and _present(hi)):  # a measurement without an interval
                return f"{float(v):+.{nd}f}"
            return f"{float(v):+.{nd}f} [{_fmt(float(lo), nd)}, {_fmt(float(hi), nd)}]"
        if c == "better" and "objects" in hidden:
            o = block.at[i, "objects"]
            return f"{int(v)}/{int(o)}" if _present(v) and _present(o) else ""
        return _fmt(v, ndp[c])

    md_rows: list[list[str]] = []
    tex_rows: list[list[str]] = []
    for bi, block in enumerate(blocks):
        formatted = pd.DataFrame({c: [cell(block, c, i) for i in block.index] for c in cols}, index=block.index)
        within = [c for c in best_within if c in block.columns] if bi == 0 else []
        rank = _ranks(block[cols], formatted, within, second if bi == 0 or footer_best else False)
        if bi > 0 and not footer_best:
            rank[:] = 0
        md_block, tex_block = [], []
        for i in block.index:
            md_cells, tex_cells = [], []
            for c in cols:
                s = formatted.at[i, c]
                r = rank.at[i, c]
                m = s.replace("|", "\\|")
                md_cells.append(f"**{m}**" if r == 1 and m else f"*{m}*" if r == 2 and m else m)
                t = _escape_tex(s)
                tex_cells.append(
                    f"\\cellcolor{{tabfirst}}{{{t}}}"
                    if r == 1 and s
                    else f"\\cellcolor{{tabsecond}}{{{t}}}"
                    if r == 2 and s
                    else t
                )
            md_block.append(md_cells)
            tex_block.append(tex_cells)
        md_rows += md_block
        tex_rows.append(tex_block)

    md = [
        "| " + " | ".join(_header(c, "md") for c in cols) + " |",
        "|" + "|".join(":--" if not pd.api.types.is_numeric_dtype(whole[c]) else "--:" for c in cols) + "|",
    ]
    md += ["| " + " | ".join(r) + " |" for r in md_rows]
    markdown = "\n".join(md) + "\n"
    if caption:
        markdown = f"{caption}\n\n{markdown}"

    align = "".join("l" if not pd.api.types.is_numeric_dtype(whole[c]) else "c" for c in cols)
    tex = [LATEX_PREAMBLE_NOTE.rstrip("\n")]
    if caption or label:
        tex += ["\\begin{table}[t]", "\\centering"]
        if caption:
            tex.append(f"\\caption{{{_escape_tex(caption)}}}")
        if label:
            tex.append(f"\\label{{{label}}}")
    tex += [
        f"\\begin{{tabular}}{{{align}}}",
        "\\toprule",
        " & ".join(_header(c, "tex") for c in cols) + " \\\\",
        "\\midrule",
    ]
    for bi, block in enumerate(tex_rows):
        if bi > 0:
            tex.append("\\midrule")
        tex += [" & ".join(r) + " \\\\" for r in block]
    tex += ["\\bottomrule", "\\end{tabular}"]
    if caption or label:
        tex.append("\\end{table}")
    return markdown, "\n".join(tex) + "\n"


def write_table(
    df: pd.DataFrame,
    path: str | os.PathLike,
    footer: pd.DataFrame | None = None,
    best_within: Sequence[str] = (),
    second: bool = False,
    decimals: Mapping[str, int] | None = None,
    caption: str | None = None,
    label: str | None = None,
    footer_best: bool = True,
) -> dict[str, Path]:
    """Write ``{stem}.csv``, ``{stem}.md`` and ``{stem}.tex`` for a table, atomically.

    Args:
        df: one row per table row; columns in display order (names as in :data:`TABLE_COLUMNS`).
        path: output path; any suffix is replaced (``results/tables/ablation`` -> ``ablation.csv|md|tex``).
        footer: optional extra rows (e.g. relighting time) shown after a rule, best-marked among themselves; its
            columns are merged into the table's (missing cells are blank).
        best_within: columns whose groups are compared separately (e.g. ``["dataset"]``).
        second: also mark the second-best value (tabsecond / italic).
        decimals: displayed decimals per column, overriding :data:`DECIMALS`.
        caption: shown above the Markdown table and as the LaTeX caption (say which metric protocol is used).
        label: LaTeX ``\\label``.
        footer_best: mark the best values among the footer rows too (False: footer rows are never marked).
    Returns {"csv": path, "md": path, "tex": path}.
    """
    path = Path(path)
    stem = path.with_suffix("") if path.suffix in (".csv", ".md", ".tex") else path
    markdown, latex = render(df, footer, best_within, second, decimals, caption, label, footer_best)
    csv_df = df if footer is None else pd.concat([df, footer], ignore_index=True)
    out = {"csv": Path(f"{stem}.csv"), "md": Path(f"{stem}.md"), "tex": Path(f"{stem}.tex")}
    with atomic_path(out["csv"]) as tmp:
        csv_df.to_csv(tmp, index=False)
    with atomic_path(out["md"]) as tmp:
        tmp.write_text(markdown)
    with atomic_path(out["tex"]) as tmp:
        tmp.write_text(latex)
    return out


# -- per-table helpers ----------------------------------------------------------------------------------


def vs_backbone(metrics: pd.DataFrame, relight_ms: Mapping[str, float]) -> tuple[pd.DataFrame, pd.DataFrame]:
    """Table 1 as (rows, footer) for :func:`write_table` (use ``best_within=["dataset"]``).

    metrics: aggregated rows with columns dataset, method, psnr, ssim, lpips and optionally psnr_interior (blank
    without) (e.g. from :func:`frng.metrics.aggregate` by ["dataset", "method"]); relight_ms: method -> relighting
    time per image in ms. The footer has one "relighting time" row per method with only ``relight_ms_per_image``
    filled.
    """
    missing = [c for c in TABLE_COLUMNS["vs_backbone"] if c not in metrics.columns and c != "psnr_interior"]
    if missing:
        raise KeyError(f"vs_backbone table: missing columns {missing}")
    rows = metrics.reindex(columns=list(TABLE_COLUMNS["vs_backbone"])).reset_index(drop=True)
    footer = pd.DataFrame(
        {
            "dataset": ["relighting time"] * len(relight_ms),
            "method": list(relight_ms),
            "relight_ms_per_image": [float(v) for v in relight_ms.values()],
        }
    )
    return rows, footer


def timing(df: pd.DataFrame, reference: str, method_col: str = "method") -> pd.DataFrame:
    """Table 5: add ``speedup`` = relight_ms_per_image of ``reference`` (e.g. the backbone) / each row's.

    df: columns method, reconstruction_s, relight_ms_per_image, resolution, spp (one row per method, same
    resolution and spp). The reference row gets speedup 1.
    """
    missing = [c for c in TABLE_COLUMNS["timing"] if c not in df.columns]
    if missing:
        raise KeyError(f"timing table: missing columns {missing}")
    ref = df.loc[df[method_col] == reference, "relight_ms_per_image"]
    if len(ref) != 1:
        raise ValueError(f"timing table: need exactly one row with {method_col} == {reference!r}, got {len(ref)}")
    out = df.loc[:, list(TABLE_COLUMNS["timing"])].copy()
    out["speedup"] = float(ref.iloc[0]) / out["relight_ms_per_image"].astype(float)
    return out
