"""Paired differences with bootstrap confidence intervals over test objects (numpy only, seeded).

Every table compares its rows with a reference row (F-RNG with the backbone, each ablation with the full model,
each view count with the rig, each K with the full model's K) on the SAME held-out images. The images of one object
are not independent (one reconstruction, one set of Gaussians), so the unit of resampling is the object:
:func:`paired_bootstrap` draws objects with replacement, and each drawn object contributes the mean of its images'
paired differences (a minus b). The interval is the percentile interval of the resampled means; the point estimate
is the plain mean over images (what the tables' metric columns average), so a table's difference column equals the
difference of its two metric columns.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

N_BOOT = 2000
SEED = 0
LEVEL = 0.95


@dataclass(frozen=True)
class PairedDiff:
    """Mean of a - b over the images (``diff``), its percentile bootstrap interval ``[lo, hi]`` over objects,
    ``better`` = objects whose mean difference is > 0 (for a higher-is-better metric: objects where a wins; the
    caller flips the sign for lower-is-better ones), ``objects`` = how many objects, ``images`` = how many pairs."""

    diff: float
    lo: float
    hi: float
    better: int
    objects: int
    images: int


def paired_bootstrap(a, b, object_ids, n: int = N_BOOT, seed: int = SEED, level: float = LEVEL) -> PairedDiff:
    """Paired bootstrap of mean(a - b) over objects.

    a, b: (N,) per-image values, paired (image i of a and of b are the same object, light and view); object_ids:
    (N,) the object of each image. Draws ``n`` resamples of the objects with replacement (numpy Generator seeded
    with ``seed``); a resample's statistic is the image-weighted mean of the drawn objects' differences (an object
    drawn twice counts twice). Returns :class:`PairedDiff`; ``lo``/``hi`` are the (1-level)/2 and (1+level)/2
    quantiles (identical inputs give [0, 0], a constant shift c gives [c, c]). NaN pairs are dropped; no pairs
    give NaNs.
    """
    a = np.asarray(a, dtype=np.float64).ravel()
    b = np.asarray(b, dtype=np.float64).ravel()
    ids = np.asarray(object_ids).ravel()
    if not (len(a) == len(b) == len(ids)):
        raise ValueError(f"paired_bootstrap: lengths differ (a {len(a)}, b {len(b)}, object_ids {len(ids)})")
    ok = np.isfinite(a) & np.isfinite(b)
    d, ids = (a - b)[ok], ids[ok]
    if not len(d):
        return PairedDiff(float("nan"), float("nan"), float("nan"), 0, 0, 0)
    objects, inv = np.unique(ids, return_inverse=True)
    sums = np.bincount(inv, weights=d, minlength=len(objects))
    counts = np.bincount(inv, minlength=len(objects)).astype(np.float64)
    rng = np.random.default_rng(seed)
    draw = rng.integers(0, len(objects), size=(int(n), len(objects)))
    boot = sums[draw].sum(axis=1) / counts[draw].sum(axis=1)
    q = (1.0 - level) / 2.0
    lo, hi = np.quantile(boot, [q, 1.0 - q])
    per_obj = sums / counts
    return PairedDiff(float(d.mean()), float(lo), float(hi), int((per_obj > 0).sum()), len(objects), len(d))


def paired(df_a, df_b, metric: str, keys=("object", "light", "view"), **kw) -> PairedDiff:
    """:func:`paired_bootstrap` of ``metric`` between two per-image frames, matched on ``keys`` (inner join: an
    image only one side has is left out). ``object`` must be among the keys."""
    keys = list(keys)
    m = df_a[keys + [metric]].merge(df_b[keys + [metric]], on=keys, suffixes=("_a", "_b"), validate="one_to_one")
    return paired_bootstrap(m[f"{metric}_a"], m[f"{metric}_b"], m["object"], **kw)
