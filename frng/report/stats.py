"""Paired differences with bootstrap confidence intervals over test objects (numpy only, seeded).

Every table compares its rows with a reference row (F-RNG with the backbone, each ablation with the full model,
each view count with the rig, each K with the full model's K) on the SAME held-out images. The images of one object
are not independent (one reconstruction, one set of Gaussians), so the unit of resampling is the object:
:func:`paired_bootstrap` draws objects with replacement, and each drawn object contributes the mean of its images'
paired differences (a minus b). The interval is the percentile interval of the resampled means; the point estimate
is the plain mean over images (what the tables' metric columns average), so a table's difference column equals the
difference of its two metric columns.

Training seeds: a side may come as several training seeds' values of the same images, (S, N). The point estimate is
then the difference of the seed means; each resample also draws that side's S seeds with replacement (one draw per
resample and side: a seed is one trained model, shared by every object) and averages the drawn seeds, so the
interval contains the spread between training runs as well as between objects (a two-level bootstrap). With one
seed on both sides it is the plain object bootstrap, resample for resample.
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
    """Paired bootstrap of mean(a - b) over objects (and over training seeds where a side has several).

    a, b: (N,) per-image values, or (S, N) the same images' values for S training seeds (S may differ between the
    sides), paired (image i of a and of b are the same object, light and view); object_ids: (N,) the object of
    each image. Draws ``n`` resamples of the objects with replacement (numpy Generator seeded with ``seed``); a
    resample's statistic is the image-weighted mean of the drawn objects' differences (an object drawn twice counts
    twice), each side's values first averaged over its seeds as drawn with replacement for that resample (module
    docstring). Returns :class:`PairedDiff`: ``diff`` is the mean over images of the seed means' difference,
    ``lo``/``hi`` the (1-level)/2 and (1+level)/2 quantiles (identical inputs give [0, 0], a constant shift c gives
    [c, c]), ``better`` counts objects whose seed-mean difference is > 0. Images with a NaN on any seed of either
    side are dropped; no pairs give NaNs.
    """
    a = np.atleast_2d(np.asarray(a, dtype=np.float64))
    b = np.atleast_2d(np.asarray(b, dtype=np.float64))
    ids = np.asarray(object_ids).ravel()
    if a.ndim != 2 or b.ndim != 2 or not (a.shape[1] == b.shape[1] == len(ids)):
        raise ValueError(
            f"paired_bootstrap: lengths differ (a {a.shape}, b {b.shape}, object_ids {len(ids)}); a and b are (N,) "
            "or (seeds, N)"
        )
    ok = np.isfinite(a).all(0) & np.isfinite(b).all(0)
    a, b, ids = a[:, ok], b[:, ok], ids[ok]
    if not len(ids):
        return PairedDiff(float("nan"), float("nan"), float("nan"), 0, 0, 0)
    d = a.mean(0) - b.mean(0)
    objects, inv = np.unique(ids, return_inverse=True)
    counts = np.bincount(inv, minlength=len(objects)).astype(np.float64)
    sums = np.bincount(inv, weights=d, minlength=len(objects))  # per object, of the seed means' difference
    rng = np.random.default_rng(seed)
    draw = rng.integers(0, len(objects), size=(int(n), len(objects)))
    if len(a) == len(b) == 1:  # one model per side: the object bootstrap
        boot = sums[draw].sum(axis=1) / counts[draw].sum(axis=1)
    else:  # per resample, each side's seeds drawn with replacement and averaged, then the objects drawn
        per_seed = [np.stack([np.bincount(inv, weights=r, minlength=len(objects)) for r in x]) for x in (a, b)]
        seed_mean = [s[rng.integers(0, len(s), size=(int(n), len(s)))].mean(axis=1) for s in per_seed]  # (n, O)
        drawn = seed_mean[0] - seed_mean[1]
        boot = np.take_along_axis(drawn, draw, axis=1).sum(axis=1) / counts[draw].sum(axis=1)
    q = (1.0 - level) / 2.0
    lo, hi = np.quantile(boot, [q, 1.0 - q])
    return PairedDiff(float(d.mean()), float(lo), float(hi), int((sums > 0).sum()), len(objects), len(d))


def paired(df_a, df_b, metric: str, keys=("object", "light", "view"), **kw) -> PairedDiff:
    """:func:`paired_bootstrap` of ``metric`` between two per-image frames, matched on ``keys`` (inner join: an
    image only one side has is left out). ``object`` must be among the keys. Either side may be a list of frames,
    one per training seed of the same model (the two-level bootstrap of the module docstring); an image is kept
    only where every frame has it."""
    keys = list(keys)
    parts_a = list(df_a) if isinstance(df_a, (list, tuple)) else [df_a]
    parts_b = list(df_b) if isinstance(df_b, (list, tuple)) else [df_b]
    cols = [f"{metric}_{i}" for i in range(len(parts_a) + len(parts_b))]
    m = None
    for col, part in zip(cols, [*parts_a, *parts_b]):
        x = part[keys + [metric]].rename(columns={metric: col})
        m = x if m is None else m.merge(x, on=keys, validate="one_to_one")
    a, b = m[cols[: len(parts_a)]].to_numpy().T, m[cols[len(parts_a) :]].to_numpy().T
    return paired_bootstrap(a, b, m["object"], **kw)
