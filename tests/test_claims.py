"""The claims table (frng/report/claims.py): each claim's verdict follows its interval and the sign the paper claims."""

import math

import numpy as np
import pandas as pd
import pytest

from frng.report import claims as C


@pytest.mark.parametrize(
    ("lo", "hi", "sign", "expected"),
    [
        (0.2, 0.9, +1, "held"),
        (-0.9, -0.2, +1, "not held"),
        (-0.1, 0.4, +1, "not resolved"),
        (-0.9, -0.2, -1, "held"),
        (0.1, 0.3, -1, "not held"),
        (-0.3, 0.1, -1, "not resolved"),
        (math.nan, math.nan, -1, "not measured"),
    ],
)
def test_verdict_is_the_interval_against_the_claimed_sign(lo, hi, sign, expected):
    assert C.verdict(lo, hi, sign) == expected


def _diff(d, lo, hi, n=10):
    return {"dpsnr": d, "dpsnr_lo": lo, "dpsnr_hi": hi, "objects": n}


def test_claims_table_reads_the_other_tables():
    labels = {"full": "F-RNG (ours)", "no-fine": "w/o fine", "no-idm": "w/o idm", "no-ind": "w/o ind"}
    labels["no-neural"] = "w/o neural"
    vs = pd.DataFrame(
        [
            {"dataset": "all", "method": "F-RNG (ours)", "dlpips": -0.01, "dlpips_lo": -0.02, "dlpips_hi": -0.005}
            | _diff(0.5, 0.2, 0.8),
            {"dataset": "diffuse", "method": "F-RNG (ours)", "dlpips": 1, "dlpips_lo": 1, "dlpips_hi": 1}
            | _diff(-5, -6, -4),
        ]
    )
    ablation = pd.DataFrame(
        [
            {"variant": "w/o fine"} | _diff(-0.3, -0.5, -0.1),
            {"variant": "w/o idm"} | _diff(0.3, 0.1, 0.5),
            {"variant": "w/o ind"} | _diff(-0.1, -0.3, 0.1),
            {"variant": "w/o neural"} | _diff(-0.3, -0.5, -0.1, n=2),  # too few objects for a verdict
        ]
    )
    t = C.claims_table(vs, ablation, {4.0: _diff(0.2, 0.1, 0.3)}, 30.0, labels).set_index("claim")
    by_key = dict(zip([c.key for c in C.CLAIMS], t["verdict"]))
    assert by_key["vs_backbone_psnr"] == "held" and by_key["vs_backbone_lpips"] == "held"
    assert by_key["speedup"] == "held" and by_key["no-fine"] == "held" and by_key["no-idm"] == "not held"
    assert by_key["no-ind"] == "not resolved" and by_key["no-neural"] == "not resolved"
    assert by_key["k4"] == "not held" and by_key["k1"] == "not measured" and by_key["k8"] == "not measured"
    assert set(t["verdict"]) <= set(C.VERDICTS) and np.isclose(t["paper"].iloc[0], 1.75)
    assert C.claims_table(vs, ablation, {}, 0.5, labels)["verdict"].iloc[2] == "not held"  # slower than the backbone
