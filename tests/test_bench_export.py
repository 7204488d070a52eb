"""``frng bench export`` (frng.diagnostics.bench_export): over a results folder laid out as ``frng relight`` leaves
it (relight/{model}/{object}/asset beside the run folders of its lights, envmaps/{light}.exr), each asset's SH fit is
the one ``frng export-asset`` reports for it; ``--floor`` fails below it; a model or object without assets is one
line naming it. The assets are tests/test_export.py's ball (two seeds, so the two objects differ)."""

from __future__ import annotations

import csv
import shutil
from pathlib import Path

import pytest
from test_export import _frng, ball_asset, sky_map


@pytest.fixture(scope="module")
def results(tmp_path_factory) -> Path:
    """relight/m/{ball0, ball1}/asset, each with two lights' run folders; the maps of one light per object only,
    plus a run folder whose map is missing (skipped)."""
    root = tmp_path_factory.mktemp("bench_export") / "results"
    sky_map(root / "envmaps" / "sky-a.exr")
    sky_map(root / "envmaps" / "sky-b.exr", height=8)
    for seed in (0, 1):
        obj = root / "relight" / "m" / f"ball{seed}"
        ball_asset(obj / "asset", n=120, seed=seed)
        for light in ("sky-a", "sky-b", "no-map"):
            (obj / light).mkdir()
    return root


def test_each_asset_fit_is_export_assets(results, tmp_path):
    r = _frng("bench", "export", results, "--lights", "2", "--out", tmp_path / "out")
    assert r.returncode == 0, r.stdout + r.stderr
    rows = list(csv.DictReader(open(tmp_path / "out" / "export.csv")))
    assert [(x["object"], x["light"]) for x in rows] == [
        ("ball0", "sky-a"), ("ball0", "sky-b"), ("ball1", "sky-a"), ("ball1", "sky-b")
    ]  # fmt: skip
    assert {x["gaussians"] for x in rows} == {"120"}
    e = _frng("export-asset", results / "relight/m/ball1/asset", "--env", results / "envmaps/sky-b.exr",
              "--format", "ply", "--out", tmp_path / "b.ply")  # fmt: skip
    assert e.returncode == 0, e.stdout + e.stderr
    assert f"SH fit PSNR {float(rows[3]['fit_psnr_db']):.1f} dB" in e.stdout, (rows[3], e.stdout)
    summary = (tmp_path / "out" / "summary.md").read_text()
    assert "| m | 4 |" in summary, summary


def test_floor_fails_below_and_missing_assets_are_named(results, tmp_path):
    r = _frng("bench", "export", results, "--objects", "ball0", "--floor", "99", "--out", tmp_path / "a")
    assert r.returncode == 1 and "below the floor 99.0 dB: m ball0 sky-a" in r.stdout, r.stdout + r.stderr
    r = _frng("bench", "export", results, "--models", "other", "--out", tmp_path / "b")
    assert r.returncode == 2 and "no assets for model 'other'" in r.stderr, r.stderr
    r = _frng("bench", "export", results, "--objects", "ball7", "--out", tmp_path / "c")
    assert r.returncode == 2 and "no asset for object 'ball7'" in r.stderr, r.stderr
    bare = tmp_path / "bare"
    shutil.copytree(results, bare, ignore=shutil.ignore_patterns("*.exr"))
    r = _frng("bench", "export", bare, "--out", tmp_path / "d")
    assert r.returncode == 2 and "no relighting light with a map" in r.stderr, r.stderr
