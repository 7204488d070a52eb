"""The quality ladder table (frng.report.paper_tables.ladder_table) and the colour-repair statistic it reports."""

import math

import numpy as np
import pandas as pd

from frng import metrics as M
from frng.report.paper_tables import LADDER_STEPS, ladder_table


def _rows(n, psnr, scale, **kw):
    return [dict(kw, psnr=psnr + 0.1 * i, ssim=0.5, lpips=0.1, scale_r=scale, scale_g=1.0, scale_b=1.0,
                 brightness_r=scale, brightness_g=scale, brightness_b=1.0) for i in range(n)]


def test_scale_log2_is_the_median_over_images_and_channels():
    df = pd.DataFrame({"scale_r": [2.0, 0.5], "scale_g": [1.0, 1.0], "scale_b": [4.0, 1.0]})
    # |log2|: 1, 0, 2, 1, 0, 0 -> median 0.5
    assert M.scale_log2(df) == 0.5
    assert math.isnan(M.scale_log2(pd.DataFrame({"psnr": [1.0]})))


def test_ladder_rows_come_from_both_evaluations():
    relit = pd.DataFrame(_rows(4, 17.0, 1.0, run="backbone") + _rows(4, 18.0, 2.0, run="full")
                         + _rows(4, 18.5, 1.0, run="full-oracle") + _rows(4, 9.0, 1.0, run="no-fine"))
    prior = pd.DataFrame(_rows(3, 25.0, 1.0, task="relight", method="gt-depth+oracle-colour")
                         + _rows(3, 22.0, 1.0, task="relight", method="backbone-geometry+oracle-colour")
                         + _rows(2, 20.0, 1.0, task="nvs", method="backbone")
                         + _rows(3, 8.0, 1.0, task="relight", method="mean-image")
                         + _rows(3, 17.5, 1.0, task="relight", method="backbone")).drop(columns=["lpips"])
    t = ladder_table(relit, prior)
    assert list(t["step"]) == [s for s, *_ in LADDER_STEPS]
    by = t.set_index("step")
    assert by.loc["a", "n"] == 3 and np.isclose(by.loc["a", "psnr"], 25.1)
    assert by.loc["c", "n"] == 2 and np.isclose(by.loc["c", "psnr"], 20.05)
    assert np.isclose(by.loc["d", "psnr"], 17.15) and np.isclose(by.loc["e", "psnr"], 18.15)
    assert np.isclose(by.loc["f", "psnr"], 18.65)
    assert math.isnan(by.loc["a", "lpips"]) and by.loc["e", "lpips"] == 0.1  # an older prior CSV without LPIPS
    # full: one channel of every image scaled by 2 -> |log2| values 1, 0, 0 per image -> median 0
    assert by.loc["e", "scale_log2"] == 0.0 and by.loc["d", "scale_log2"] == 0.0
    # full: two channels of every image 2x too dark by the ratio of means -> median 1
    assert by.loc["e", "brightness_log2"] == 1.0 and by.loc["d", "brightness_log2"] == 0.0


def test_ladder_takes_the_prior_rows_lpips_when_recorded():
    relit = pd.DataFrame(_rows(2, 18.0, 1.0, run="full"))
    prior = pd.DataFrame(_rows(2, 22.0, 1.0, task="relight", method="backbone-geometry+oracle-colour"))
    prior["lpips"] = [0.04, 0.06]
    by = ladder_table(relit, prior).set_index("step")
    assert np.isclose(by.loc["b", "lpips"], 0.05) and by.loc["e", "lpips"] == 0.1


def test_ladder_skips_rows_it_has_no_data_for():
    relit = pd.DataFrame(_rows(2, 17.0, 1.0, run="backbone") + _rows(2, 18.0, 1.0, run="full"))
    prior = pd.DataFrame(_rows(2, 20.0, 1.0, task="nvs", method="backbone"))
    assert list(ladder_table(relit, prior)["step"]) == ["c", "d", "e"]


def test_oracle_run_stays_out_of_the_paper_tables():
    from frng.report.paper_tables import ablation_rows, k_rows, views_rows

    rows = []
    for run, variant, psnr in (("full", "full", 18.0), ("full-oracle", "full", 30.0), ("no-fine", "no-fine", 17.0)):
        rows += _rows(2, psnr, 1.0, run=run, variant=variant, views=6, method="F-RNG", k=2.0)
    df = pd.DataFrame(rows)
    for sub in (ablation_rows(df), k_rows(df), views_rows(df)):
        assert "full-oracle" not in set(sub["run"]) and len(sub)
