"""The paper's claims beside this tier's measurements (table ``claims``): each claim of Table 1 (F-RNG vs RelitLRM),
Table 4 (the ablation) and the K table, the paper's number, this tier's difference with its 95 % paired bootstrap
interval (over test objects, and training seeds where there are several), and a verdict:

- ``held``: the interval lies on the claimed side of 0;
- ``not held``: it lies on the other side;
- ``not resolved``: it contains 0 (this tier cannot tell);
- ``not measured``: the tier has no such run (e.g. K = 2 % not in the sweep).

An interval over fewer than :data:`MIN_OBJECTS` test objects resamples nothing (the smoke tier has one): such a
claim is ``not resolved`` whatever its sign.

The verdict is about the sign the paper claims, not its size: the ``paper`` and ``measured`` columns show both. The
paper's numbers (:data:`CLAIMS`) are copied from its tables (Objaverse, aligned protocol); they are differences in
the same direction as the measured ones (row minus its reference).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import pandas as pd

VERDICTS = ("held", "not held", "not resolved", "not measured")
MIN_OBJECTS = 3  # fewer test objects: no verdict but "not resolved"


@dataclass(frozen=True)
class Claim:
    """One claim: ``text`` (what the paper says), ``source`` (its table), ``metric`` (psnr | lpips | speedup),
    ``paper`` (the paper's difference, row minus reference; for speedup the factor), ``sign`` (+1: the claim is a
    difference above 0 (speed-up above 1), -1: below 0)."""

    key: str
    text: str
    source: str
    metric: str
    paper: float
    sign: int


# Table 1 (Objaverse: F-RNG 31.77 / 0.945 / 0.047, RelitLRM 30.02 / 0.950 / 0.049; ~25x faster relighting);
# Table 4 (256 px: full 32.44; w/o fine 31.46, w/o IDM 31.21, w/o L_ind 32.07, w/o neural 31.72);
# the K table (K = 1 / 2 / 4 / 8 %: 31.05 / 31.77 / 31.70 / 31.54).
CLAIMS: tuple[Claim, ...] = (
    Claim("vs_backbone_psnr", "F-RNG relights better than its backbone (PSNR)", "Table 1", "psnr", 31.77 - 30.02, +1),
    Claim("vs_backbone_lpips", "F-RNG relights better than its backbone (LPIPS)", "Table 1", "lpips", -0.002, -1),
    Claim("speedup", "F-RNG relights faster than its backbone (x)", "Table 1", "speedup", 25.0, +1),
    Claim("no-fine", "w/o fine-grained Gaussians is worse than the full model", "Table 4", "psnr", 31.46 - 32.44, -1),
    Claim("no-idm", "w/o IDM priors is worse than the full model", "Table 4", "psnr", 31.21 - 32.44, -1),
    Claim("no-ind", "w/o light-independence regularisation is worse", "Table 4", "psnr", 32.07 - 32.44, -1),
    Claim("no-neural", "w/o neural appearance modelling is worse", "Table 4", "psnr", 31.72 - 32.44, -1),
    Claim("k1", "K = 1 % is worse than K = 2 %", "K table", "psnr", 31.05 - 31.77, -1),
    Claim("k4", "K = 4 % is worse than K = 2 %", "K table", "psnr", 31.70 - 31.77, -1),
    Claim("k8", "K = 8 % is worse than K = 2 %", "K table", "psnr", 31.54 - 31.77, -1),
)


def verdict(lo: float, hi: float, sign: int) -> str:
    """The verdict of an interval [lo, hi] on a claim of sign ``sign`` (module docstring)."""
    if not (math.isfinite(lo) and math.isfinite(hi)):
        return "not measured"
    if sign > 0:
        return "held" if lo > 0 else "not held" if hi < 0 else "not resolved"
    return "held" if hi < 0 else "not held" if lo > 0 else "not resolved"


def _row(c: Claim, measured: float, lo: float, hi: float, n: float = np.nan) -> dict:
    if c.metric == "speedup":  # a factor without an interval: judged on its log against 0
        x = math.log(measured) if math.isfinite(measured) and measured > 0 else float("nan")
        v = verdict(x, x, c.sign)
    else:
        v = verdict(lo, hi, c.sign)
        if v in ("held", "not held") and not (math.isfinite(n) and n >= MIN_OBJECTS):
            v = "not resolved"
    return {
        "claim": c.text,
        "source": c.source,
        "paper": c.paper,
        "measured": measured,
        "measured_lo": lo,
        "measured_hi": hi,
        "objects": n,
        "verdict": v,
    }


def claims_table(
    vs_backbone: pd.DataFrame,
    ablation: pd.DataFrame,
    k_diffs: dict[float, dict],
    speedup: float,
    labels: dict,
    protocol: str = "aligned",
    psnr_only: bool = False,
) -> pd.DataFrame:
    """The claims table from the other tables' rows.

    vs_backbone: the ``vs_backbone`` table (its ``all`` row of F-RNG, labelled ``labels['full']``, carries the paired
    difference to the backbone); ablation: the ``ablation`` table (an ablation's row labelled ``labels[variant]``);
    k_diffs:
    {K in %: paired-difference columns (``dpsnr``, ``dpsnr_lo``, ``dpsnr_hi``, ``objects``) of that K minus K = 2 %}
    (empty without K = 2 %); speedup: the backbone's relighting time per image over F-RNG's (NaN: not timed);
    protocol: the metric protocol the tables were computed under (a column of every row); psnr_only: only the PSNR
    claims (a second protocol's pass, where LPIPS and the timing were not re-measured)."""
    rows = []
    nan = float("nan")
    full = vs_backbone[(vs_backbone["dataset"] == "all") & (vs_backbone["method"] == labels["full"])]
    for c in CLAIMS:
        if psnr_only and c.metric != "psnr":
            continue
        if c.key.startswith("vs_backbone"):
            m = c.metric
            r = full.iloc[0] if len(full) else None
            cells = (nan, nan, nan, nan) if r is None else (r[f"d{m}"], r[f"d{m}_lo"], r[f"d{m}_hi"], r["objects"])
            rows.append(_row(c, *cells))
        elif c.key == "speedup":
            rows.append(_row(c, speedup, nan, nan))
        elif c.key in labels:
            a = ablation[ablation["variant"] == labels[c.key]]
            r = a.iloc[0] if len(a) else None
            cells = (nan, nan, nan, nan) if r is None else (r["dpsnr"], r["dpsnr_lo"], r["dpsnr_hi"], r["objects"])
            rows.append(_row(c, *cells))
        else:  # the K sweep: k{P} minus K = 2 %
            d = k_diffs.get(float(c.key[1:]))
            cells = (nan, nan, nan, nan) if d is None else (d["dpsnr"], d["dpsnr_lo"], d["dpsnr_hi"], d["objects"])
            rows.append(_row(c, *cells))
    return pd.DataFrame(rows).assign(protocol=protocol)


__all__ = ["CLAIMS", "Claim", "VERDICTS", "claims_table", "verdict"]
