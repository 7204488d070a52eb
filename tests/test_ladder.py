"""The quality ladder table (frng.report.ladder.ladder_table) and the colour-repair statistic it reports."""

import math

import numpy as np
import pandas as pd
from data_helpers import protocol_scores

from frng import metrics as M
from frng.report.ladder import LADDER_STEPS, REFERENCE_HALF_METHOD, TARGETS_METHOD, ladder_table


def _rows(n, psnr, scale, **kw):
    return [
        dict(
            kw,
            object=f"o{i % 2}",
            light="l0",
            view=f"v{i}",
            **protocol_scores(psnr + 0.1 * i, scale=(scale, 1.0, 1.0), brightness=(scale, scale, 1.0)),
        )
        for i in range(n)
    ]


def test_scale_log2_is_the_median_over_images_and_channels():
    df = pd.DataFrame({"scale_r": [2.0, 0.5], "scale_g": [1.0, 1.0], "scale_b": [4.0, 1.0]})
    # |log2|: 1, 0, 2, 1, 0, 0 -> median 0.5
    assert M.scale_log2(df) == 0.5
    assert math.isnan(M.scale_log2(pd.DataFrame({"psnr": [1.0]})))


def test_ladder_rows_come_from_both_evaluations():
    relit = pd.DataFrame(
        _rows(4, 17.0, 1.0, run="backbone")
        + _rows(4, 18.0, 2.0, run="full")
        + _rows(4, 18.5, 1.0, run="full-oracle")
        + _rows(4, 9.0, 1.0, run="no-fine")
        + _rows(4, 18.25, 1.0, run="plus")
        + _rows(4, 17.75, 1.0, run="plus-base")
        + _rows(4, 18.5, 1.0, run="plus-known-light")
        + _rows(4, 30.0, 1.0, run="full@s1")
    )
    prior = pd.DataFrame(
        _rows(2, 40.0, 1.0, task="relight", method=REFERENCE_HALF_METHOD)  # frng noise-floor's rows
        + _rows(2, 36.0, 1.0, task="relight", method=TARGETS_METHOD)
        + _rows(3, 25.0, 1.0, task="relight", method="gt-depth+oracle-colour")
        + _rows(3, 22.0, 1.0, task="relight", method="backbone-geometry+oracle-colour")
        + _rows(2, 20.0, 1.0, task="nvs", method="backbone")
        + _rows(3, 8.0, 1.0, task="relight", method="mean-image")
        + _rows(3, 17.5, 1.0, task="relight", method="backbone")
    ).drop(columns=["lpips"])
    t = ladder_table(relit, prior)
    assert list(t["step"]) == [s for s, *_ in LADDER_STEPS]
    by = t.set_index("step")
    assert by.loc["0", "n"] == 2 and np.isclose(by.loc["0", "psnr"], 36.05)  # the targets' noise floor
    assert np.isclose(by.loc["0r", "psnr"], 40.05)  # its reference's own noise
    assert by.loc["a", "n"] == 3 and np.isclose(by.loc["a", "psnr"], 25.1)
    assert by.loc["c", "n"] == 2 and np.isclose(by.loc["c", "psnr"], 20.05)
    assert np.isclose(by.loc["d", "psnr"], 17.15) and np.isclose(by.loc["e", "psnr"], 18.15)
    assert np.isclose(by.loc["f", "psnr"], 18.65) and np.isclose(by.loc["g", "psnr"], 17.9)
    # paired differences to the reference step, a constant shift per image: the interval is the shift itself
    assert by.loc["e", "vs"] == "d" and by.loc["f", "vs"] == "e" and by.loc["g", "vs"] == "e+"
    assert by.loc["e+", "vs"] == "e" and by.loc["h", "vs"] == "e+"  # F-RNG+ and its oracle told the input light
    for step, d in (("e", 1.0), ("f", 0.5), ("e+", 0.25), ("g", -0.5), ("h", 0.25)):
        assert np.isclose(by.loc[step, "dpsnr"], d), step
        assert np.isclose(by.loc[step, "dpsnr_lo"], d) and np.isclose(by.loc[step, "dpsnr_hi"], d), step
        assert by.loc[step, "dssim"] == 0 and by.loc[step, "objects"] == 2
    assert by.loc["e", "better"] == 2 and by.loc["g", "better"] == 0
    assert pd.isna(by.loc["d", "dpsnr"]) and pd.isna(by.loc["a", "dpsnr"])
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


def _cross(run, light, against, psnr, ssim=0.5, lpips=0.2, objects=("o0", "o1")):
    return [
        dict(
            run=run,
            light=light,
            scored_against=against,
            object=o,
            view="v0",
            psnr=psnr + k,
            ssim=ssim,
            lpips=lpips,
            dataset="diffuse",
        )
        for k, o in enumerate(objects)
    ]


def test_light_sensitivity_rows_are_right_minus_wrong_light():
    # two objects, two lights, one view; right-light scores from the per-image rows
    relit = pd.DataFrame(
        [
            dict(
                run=r,
                object=o,
                light=l,
                view="v0",
                **protocol_scores(p + k, ssim=0.6, brightness=(1.0, 1.0, 1.0)),
            )
            for r, p in (("backbone", 17.0), ("full", 18.0))
            for k, o in enumerate(("o0", "o1"))
            for l in ("l0", "l1")
        ]
    )
    cross = pd.DataFrame(
        _cross("backbone", "l0", "l1", 16.5)
        + _cross("backbone", "l1", "l0", 16.5)  # backbone: 0.5 dB light-aware
        + _cross("full", "l0", "l1", 16.0)
        + _cross("full", "l1", "l0", 16.0)  # F-RNG: 2 dB
        + _cross("ground-truth", "l0", "l1", 15.0, ssim=0.7, lpips=0.05)
        + _cross("ground-truth", "l1", "l0", 15.0, ssim=0.7, lpips=0.05)
        + _cross("ground-truth", "l0", "l0", 100.0, ssim=1.0, lpips=0.0)
        + _cross("ground-truth", "l1", "l1", 100.0, ssim=1.0, lpips=0.0)
    )
    by = ladder_table(relit, pd.DataFrame(columns=["task", "method", "psnr", "ssim"]), cross).set_index("step")
    assert list(by.index) == ["d", "e", "s1", "s2", "s3"]
    assert np.isclose(by.loc["s1", "psnr"], 17.0) and by.loc["s1", "n"] == 4  # the wrong-light score
    assert np.isclose(by.loc["s1", "dpsnr"], 0.5) and np.isclose(by.loc["s2", "dpsnr"], 2.0)
    assert np.isclose(by.loc["s2", "dpsnr_lo"], 2.0) and np.isclose(by.loc["s2", "dpsnr_hi"], 2.0)
    assert np.isclose(by.loc["s2", "dssim"], 0.1) and np.isclose(by.loc["s2", "dlpips"], -0.1)
    assert np.isclose(by.loc["s3", "psnr"], 15.5) and np.isnan(by.loc["s3", "dpsnr"])  # identical images: no dB
    assert np.isclose(by.loc["s3", "dssim"], 0.3) and np.isclose(by.loc["s3", "dlpips"], -0.05)
    assert (by.loc[["s1", "s2", "s3"], "vs"] == "right light").all() and by.loc["s2", "better"] == 2


def test_lambertian_table_per_material_class():
    from frng.report.paper_tables import lambertian_table

    rows = []
    for run, shift in (("plus", 0.0), ("plus-base", -0.5), ("backbone", -2.0)):
        for ds, o, base in (("diffuse", "o0", 20.0), ("fur", "o1", 15.0)):
            rows += [
                dict(
                    run=run,
                    dataset=ds,
                    object=o,
                    light=l,
                    view="v0",
                    **protocol_scores(base + shift + i),
                )
                for i, l in enumerate(("l0", "l1"))
            ]
    t = lambertian_table(pd.DataFrame(rows))
    assert list(t["dataset"]) == ["diffuse", "diffuse", "fur", "fur", "all", "all"]
    base = t[t["method"] == "Lambertian base only"].set_index("dataset")
    frng = t[t["method"] != "Lambertian base only"].set_index("dataset")
    assert np.isclose(frng.loc["diffuse", "psnr"], 20.5) and np.isclose(base.loc["fur", "psnr"], 15.0)
    assert np.allclose(base["dpsnr"], -0.5) and np.allclose(base["dpsnr_lo"], -0.5) and frng["dpsnr"].isna().all()
    assert list(base["objects"]) == [1, 1, 2] and list(base["n"]) == [2, 2, 4]


def test_oracle_run_stays_out_of_the_paper_tables():
    from frng.report.paper_tables import ablation_rows, k_rows, views_rows

    rows = []
    for run, variant, psnr in (("full", "full", 18.0), ("full-oracle", "full", 30.0), ("no-fine", "no-fine", 17.0)):
        rows += _rows(2, psnr, 1.0, run=run, variant=variant, views=6, method="F-RNG", k=2.0)
    df = pd.DataFrame(rows)
    for sub in (ablation_rows(df), k_rows(df), views_rows(df)):
        assert "full-oracle" not in set(sub["run"]) and len(sub)
