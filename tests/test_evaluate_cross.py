"""frng.apps.scoring's light-sensitivity CSV: each image scored against the ground truth of the next test light."""

from pathlib import Path

import numpy as np
import pytest

from frng import io
from frng import metrics as M
from frng.apps import scoring as E
from frng.plan.layout import Layout, RelightFolder


def _img(value, shadow, size=32):
    rgba = np.zeros((size, size, 4), np.float32)
    rgba[8:24, 8:24, :3] = value
    rgba[8:24, 8:24, 3] = 1.0
    rgba[shadow] *= np.array([0.3, 0.3, 0.3, 1.0], np.float32)  # where the light does not reach: a per-channel
    return rgba  # scale (the aligned protocol) cannot turn one light's shading into another's


def _write(path, arr):
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    io.write_exr(path, arr, channels=["R", "G", "B", "A"])


def test_other_light_is_the_next_one_cyclically():
    assert M.other_light(["a", "b", "c"], "a") == "b" and M.other_light(["a", "b", "c"], "c") == "a"
    assert M.other_light(["a"], "a") == "a"


def test_cross_light_rows(tmp_path):
    L = Layout(tmp_path)
    oid, lights, views = "obj_0000", ["l0", "l1"], ["t0"]
    meta = Path(L.object_meta(oid))
    meta.parent.mkdir(parents=True)
    io.write_json(meta, {"material_class": "fur"})
    gt = {
        "l0": _img(np.array([0.8, 0.2, 0.2]), np.s_[8:24, 16:24]),
        "l1": _img(np.array([0.1, 0.3, 0.9]), np.s_[8:16, 8:24]),
    }
    for light in lights:
        _write(L.object_image(oid, "targets", light, "t0"), gt[light])
    # a "method" whose image for each light is the OTHER light's ground truth: perfect against the wrong light
    run_dir = tmp_path / "relight" / "backbone" / oid
    io.write_json(
        RelightFolder(run_dir).record(),
        {"object": oid, "name": "backbone", "method": "backbone", "lights": lights, "target_views": views},
    )
    for light in lights:
        _write(RelightFolder(run_dir).image(light, "t0"), gt[M.other_light(lights, light)])
    rows = E.cross_light_run(tmp_path, run_dir, "aligned", (1.0, 1.0, 1.0))
    assert [(r["light"], r["scored_against"]) for r in rows] == [("l0", "l1"), ("l1", "l0")]
    assert all(r["psnr"] == 100.0 and r["run"] == "backbone" and r["dataset"] == "fur" for r in rows)
    gt_rows = E.cross_light_run(tmp_path, run_dir, "aligned", (1.0, 1.0, 1.0), ground_truth=True)
    assert [(r["light"], r["scored_against"]) for r in gt_rows] == [
        ("l0", "l1"),
        ("l0", "l0"),
        ("l1", "l0"),
        ("l1", "l1"),
    ]
    own = [r for r in gt_rows if r["light"] == r["scored_against"]]
    other = [r for r in gt_rows if r["light"] != r["scored_against"]]
    assert all(r["psnr"] == 100.0 and r["ssim"] == pytest.approx(1.0) for r in own)
    assert all(r["psnr"] < 100.0 and r["run"] == "ground-truth" for r in other)
