"""Other methods' outputs on the smoke tier (issue 54): folders written by the test from the smoke run's own ground
truth -- a per-scene method as linear EXR, an image-based one as 8-bit sRGB PNG at twice the size -- listed in
``baselines.external`` give their rows in Tables 2 and 3 through the stages the workflow runs (``frng baseline-eval``,
``frng baseline-tables``), and a missing or mis-sized file stops the scoring with one line naming it."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import yaml
from conftest import ROOT, copy_results

from frng import io


def _frng(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "frng", *args], cwd=ROOT, capture_output=True, text=True, timeout=600)


def test_external_folders_give_rows_in_tables_2_and_3(smoke_pipeline, tmp_path):
    from frng.data.dataset import open_object
    from frng.metrics import read_csv
    from frng.plan import catalog

    results = copy_results(smoke_pipeline, tmp_path / "results")
    cfg = yaml.safe_load((ROOT / "config" / "smoke.yaml").read_text())
    cfg["results"] = str(results)
    dense, image = tmp_path / "dense_exr", tmp_path / "image_png"
    test_ids = catalog.plan(cfg).split("test")
    for oid in test_ids:
        obj = open_object(results, oid)
        names = obj.view_names("targets")
        for light in obj.target_lights:
            for name, rgba in zip(names, obj.images("targets", light, None)):
                io.write_exr(dense / oid / light / f"{name}.exr", rgba)  # linear, premultiplied: exact
                big = np.repeat(np.repeat(rgba, 2, 0), 2, 1)
                a = big[..., 3:4]
                straight = np.where(a > 0, big[..., :3] / np.maximum(a, 1e-6), 0.0)
                png = image / oid / light / f"{name}.png"
                png.parent.mkdir(parents=True, exist_ok=True)
                io.write_png(png, np.concatenate([io.srgb_encode(straight), a], -1))
    cfg["baselines"]["external"] = [
        {"name": "gtexr", "path": str(dense), "encoding": "linear", "family": "dense"},
        {"name": "gtpng", "path": str(image), "encoding": "srgb", "family": "image"},
    ]
    path = tmp_path / "smoke_ext.yaml"
    path.write_text(yaml.safe_dump(cfg))

    r = _frng("baseline-eval", "--config", str(path))
    assert r.returncode == 0, (r.stdout + r.stderr)[-3000:]
    r = _frng("baseline-tables", "--config", str(path), "--no-figures")
    assert r.returncode == 0, (r.stdout + r.stderr)[-3000:]
    tables = results / "tables"
    dense_rows = read_csv(tables / "vs_dense.csv").set_index(["dataset", "method"])
    row = dense_rows.loc[("all", "gtexr (per-scene, from files)")]
    assert row["source"] == "files" and row["psnr"] == 100.0 and row["dpsnr_lo"] > 0  # the ground truth itself
    img_rows = read_csv(tables / "vs_image_based.csv").set_index(["dataset", "method"])
    row = img_rows.loc[("all", "gtpng (image-based, from files)")]
    assert row["source"] == "files" and row["psnr"] > 40.0 and row["n"] == dense_rows.loc[("all", "F-RNG (ours)"), "n"]
    found = read_csv(tables / "baseline_findings.csv")
    assert found["what"].str.startswith("gtpng, relighting").any()

    # a missing file, then one of another aspect ratio: one line naming it, exit 2
    oid, light = test_ids[0], open_object(results, test_ids[0]).target_lights[0]
    victim = sorted((image / oid / light).glob("*.png"))[0]
    victim.unlink()
    r = _frng("baseline-eval", "--config", str(path))
    out = r.stdout.strip().splitlines()
    assert r.returncode == 2 and len(out) == 1 and str(victim.with_suffix("")) in out[0] and "missing" in out[0], out
    io.write_png(victim, np.zeros((20, 30, 4), np.float32))
    r = _frng("baseline-eval", "--config", str(path))
    out = r.stdout.strip().splitlines()
    assert r.returncode == 2 and len(out) == 1 and str(victim) in out[0] and "30x20" in out[0], out
