"""Benchmarks in the workflow (rules/benchmarks.smk): a config naming benchmark folders plans offline (`make dry-run`
runs `snakemake -n`), bad `benchmarks:` entries fail before any job, and -- the smoke tier end to end -- one curated
test object exported in each published layout is imported back, relit by the trained smoke models and scored with
its benchmark's own protocol into tables/benchmarks."""

from __future__ import annotations

import re
import subprocess
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import yaml
from conftest import ROOT, copy_results, venv_bin

LAYOUTS = ["tensoir", "orb", "owl", "nerf-synthetic"]


def _snakemake(configfile: Path, *extra, timeout=300):
    cmd = [venv_bin("snakemake"), "--snakefile", "workflow/Snakefile", "--configfile", str(configfile), *extra]
    return subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=timeout)


def _config(tmp: Path, results: Path, benchmarks: list[dict]) -> Path:
    cfg = yaml.safe_load((ROOT / "config" / "smoke.yaml").read_text())
    cfg["results"] = str(results)
    cfg["benchmarks"] = benchmarks
    path = tmp / "bench.yaml"
    path.write_text(yaml.safe_dump(cfg))
    return path


@pytest.fixture(scope="module")
def exported(tmp_path_factory):
    """The analytic curated object of tests/test_benchmarks.py, exported in every layout."""
    from test_benchmarks import make_curated

    from frng.benchmarks import export_object

    base = tmp_path_factory.mktemp("bench_wf")
    make_curated(base / "src")
    return {l: export_object(l, base / "src", "obj_0000", base / "export" / l) for l in LAYOUTS}


def test_dry_run_of_a_config_naming_benchmarks_plans_offline(exported, tmp_path):
    cfg = _config(tmp_path, tmp_path / "results", [{"layout": l, "path": str(p)} for l, p in exported.items()])
    proc = subprocess.run(["make", "dry-run", f"CONFIG={cfg}"], cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, (proc.stdout + proc.stderr)[-3000:]
    out = proc.stdout + proc.stderr
    counts = {
        k: int(v) for k, v in (l.split() for l in out.splitlines() if len(l.split()) == 2 and l.split()[1].isdigit())
    }
    assert counts.get("import_benchmark") == 4 and counts.get("relight_benchmark") == 4, out[-2000:]
    assert counts.get("evaluate_benchmarks") == 1
    assert not (tmp_path / "results" / "objects").exists()  # planning wrote nothing


def test_bad_benchmark_entries_fail_before_any_job(exported, tmp_path):
    p = str(exported["tensoir"])
    cfg = _config(tmp_path, tmp_path / "results", [{"layout": "tensoir", "path": p}, {"layout": "tensoir", "path": p}])
    proc = _snakemake(cfg, "-n", "--quiet", "rules")
    assert proc.returncode != 0 and "both import to 'tensoir-obj_0000'" in proc.stdout + proc.stderr
    cfg = _config(tmp_path, tmp_path / "results", [{"layout": "mitsuba", "path": p}])
    proc = _snakemake(cfg, "-n", "--quiet", "rules")
    assert proc.returncode != 0 and "benchmarks" in proc.stdout + proc.stderr


def test_smoke_tier_exported_imported_relit_scored(smoke_pipeline, tmp_path, capsys):
    """Export the smoke tier's curated test object in every layout, then run the workflow's benchmark target on a
    copy of the session's smoke run (conftest.smoke_pipeline): import -> relight (the trained smoke models and the
    backbone) -> each benchmark's protocol; nothing the smoke run made is redone."""
    from frng import cli
    from frng.plan import catalog
    from frng.plan import config as frng_config

    results = copy_results(smoke_pipeline, tmp_path / "results")
    cfg0 = _config(tmp_path, results, [])
    config = frng_config.load(cfg0)
    oid = catalog.plan(config).split("test")[0]
    paths = {}
    for layout in LAYOUTS:  # `frng export` in this process (its command line; a subprocess each cost ~2 s CPU)
        args = cli.stage_parser("export").parse_args(
            ["--config", str(cfg0), "--layout", layout, "--object", oid, "--out", str(tmp_path / "export" / layout)]
        )
        capsys.readouterr()
        assert cli.run_stage("export", args._run, args) == 0, capsys.readouterr()
        paths[layout] = capsys.readouterr().out.strip().splitlines()[-1]
    cfg = _config(tmp_path, results, [{"layout": l, "path": p} for l, p in paths.items()])
    r = _snakemake(
        cfg,
        "--profile",
        "profiles/local",
        "--config",
        "overwrite_config=true",
        "--cores",
        "2",
        "evaluate_benchmarks",
        timeout=1800,
    )  # --config/--configfile take several values: target last
    assert r.returncode == 0, (r.stdout + r.stderr)[-3000:]
    ran = set(re.findall(r"Finished jobid: \d+ \(Rule: (\w+)\)", r.stdout + r.stderr))
    bench_rules = {"import_benchmark", "relight_benchmark", "evaluate_benchmarks"}
    # the copy is up to date: nothing but the benchmark rules and the digest of the changed config section reran
    assert bench_rules <= ran <= bench_rules | {"config_digest"}, ran
    table = pd.read_csv(results / "tables" / "benchmarks.csv")
    assert set(table["benchmark"]) == set(LAYOUTS)
    assert set(zip(table["benchmark"], table["protocol"])) == {(l, l) for l in LAYOUTS}
    assert len(table) == 2 * len(LAYOUTS)  # F-RNG and the backbone per benchmark
    assert np.isfinite(table["psnr"]).all() and (table["psnr"] > 5).all()
    assert np.isfinite(table.loc[table["benchmark"] == "orb", "psnr_l"]).all()
    per_image = pd.read_csv(results / "metrics" / "benchmarks_per_image.csv")
    assert set(per_image["run"]) == {"full", "backbone"}
    caption = (results / "tables" / "benchmarks.md").read_text().splitlines()[0]
    assert all(p in caption for p in ("tensoir", "orb", "owl", "nerf-synthetic"))
