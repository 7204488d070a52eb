"""frng.report.stats.paired_bootstrap: hand-checkable cases of the paired bootstrap over objects (and seeds)."""

import numpy as np
import pandas as pd
import pytest

from frng.report.stats import paired, paired_bootstrap


def test_identical_inputs_give_zero():
    a = np.array([18.0, 19.5, 17.2, 20.1])
    r = paired_bootstrap(a, a, ["o1", "o1", "o2", "o2"])
    assert (r.diff, r.lo, r.hi, r.better, r.objects, r.images) == (0.0, 0.0, 0.0, 0, 2, 4)


def test_constant_shift_gives_that_shift():
    b = np.array([18.0, 19.5, 17.2, 20.1, 16.0, 15.0])
    r = paired_bootstrap(b + 0.25, b, ["a", "a", "b", "b", "c", "c"])
    assert r.diff == pytest.approx(0.25) and r.lo == pytest.approx(0.25) and r.hi == pytest.approx(0.25)
    assert r.better == 3 and r.objects == 3


def test_two_objects_by_hand():
    # object x: differences 1, 3 (mean 2, 2 images); object y: difference -1 (1 image)
    a, b, ids = [1.0, 3.0, -1.0], [0.0, 0.0, 0.0], ["x", "x", "y"]
    r = paired_bootstrap(a, b, ids, n=4000, seed=1)
    assert r.diff == pytest.approx(1.0)  # the plain mean over images: (1 + 3 - 1) / 3
    # resamples: {x, x} -> 2, {y, y} -> -1, {x, y} -> (4 - 1) / 3 = 1; each object drawn with p = 1/2, so
    # P(2) = P(-1) = 1/4: the 2.5% and 97.5% quantiles are -1 and 2
    assert r.lo == -1.0 and r.hi == 2.0
    assert r.better == 1 and r.objects == 2 and r.images == 3


def test_seeded_and_resamples_objects_not_images():
    rng = np.random.default_rng(0)
    ids = np.repeat(np.arange(8), 12)
    obj_effect = rng.normal(0, 1, 8)[ids]  # a per-object effect, shared by all its images
    a = obj_effect + rng.normal(0, 0.01, len(ids))
    b = np.zeros(len(ids))
    r1, r2 = paired_bootstrap(a, b, ids, seed=3), paired_bootstrap(a, b, ids, seed=3)
    assert r1 == r2
    # resampling images would give an interval ~sqrt(12) times narrower than the objects' spread warrants
    per_image = paired_bootstrap(a, b, np.arange(len(ids)), seed=3)
    assert (r1.hi - r1.lo) > 2.5 * (per_image.hi - per_image.lo)
    assert r1.lo < r1.diff < r1.hi


def test_paired_matches_on_keys_and_nan_pairs_are_dropped():
    da = pd.DataFrame(
        {"object": ["o", "o", "p"], "light": ["l1", "l2", "l1"], "view": ["v", "v", "v"], "psnr": [20.0, 21.0, np.nan]}
    )
    db = da.iloc[::-1].assign(psnr=[5.0, 19.0, 18.0])  # p/l1 -> 5 (NaN in a), o/l2 -> 19, o/l1 -> 18
    r = paired(da, db, "psnr")
    assert r.images == 2 and r.objects == 1 and r.diff == pytest.approx(2.0)
    with pytest.raises(ValueError, match="lengths differ"):
        paired_bootstrap([1.0], [1.0, 2.0], ["o"])


def test_one_seed_as_a_row_is_the_object_bootstrap():
    rng = np.random.default_rng(2)
    ids = np.repeat(np.arange(6), 4)
    a, b = rng.normal(18, 1, len(ids)), rng.normal(17.5, 1, len(ids))
    assert paired_bootstrap(a[None], b[None], ids) == paired_bootstrap(a, b, ids)


def test_training_seeds_are_resampled_with_the_objects():
    # two seeds of a, shifted +1 and +3 over b on every image of every object: the seed mean is +2; the object
    # draws cannot move it, the seed draws give {+1, +1} (p 1/4), mixed +2 (p 1/2), {+3, +3} (p 1/4)
    b = np.array([18.0, 19.5, 17.2, 20.1, 16.0, 15.0])
    ids = ["a", "a", "b", "b", "c", "c"]
    r = paired_bootstrap(np.stack([b + 1.0, b + 3.0]), b, ids, n=4000)
    assert r.diff == pytest.approx(2.0) and r.lo == pytest.approx(1.0) and r.hi == pytest.approx(3.0)
    assert r.better == 3 and r.objects == 3 and r.images == 6
    # the object-only interval of the seed means would claim [2, 2]
    assert paired_bootstrap(b + 2.0, b, ids).hi == pytest.approx(2.0)
    # a NaN on any seed drops that image
    a = np.stack([b + 1.0, b + 3.0])
    a[1, 0] = np.nan
    assert paired_bootstrap(a, b, ids).images == 5


def test_paired_takes_one_frame_per_seed():
    keys = {"object": ["o", "o", "p"], "light": ["l1", "l2", "l1"], "view": ["v", "v", "v"]}
    ref = pd.DataFrame({**keys, "psnr": [18.0, 19.0, 17.0]})
    s0 = ref.assign(psnr=ref["psnr"] + 0.5)
    s1 = ref.iloc[::-1].assign(psnr=ref["psnr"].iloc[::-1] + 1.5).iloc[:2]  # has only o/l2 and p/l1
    r = paired([s0, s1], ref, "psnr")
    assert r.images == 2 and r.diff == pytest.approx(1.0)  # images every seed has; mean of +0.5 and +1.5
    assert r.lo == pytest.approx(0.5) and r.hi == pytest.approx(1.5)
