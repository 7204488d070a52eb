"""``frng bench train`` on the smoke run's data: the real trainers' steps timed per thread count, nothing written
under the results folder, and the per-step times read from a trainer's loss.csv."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest
import yaml
from conftest import ROOT

from frng.diagnostics.bench_train import _step_seconds


def test_step_seconds_are_the_differences_after_the_skipped_steps(tmp_path):
    (tmp_path / "loss.csv").write_text("step,elapsed_s,total\n1,5.0,1\n2,5.5,1\n3,6.25,1\n4,7.25,1\n")
    assert _step_seconds(tmp_path / "loss.csv", 1) == pytest.approx([0.75, 1.0])


def test_bench_train_times_both_trainers_on_the_smoke_data(smoke_pipeline, tmp_path):
    cfg = yaml.safe_load((ROOT / "config" / "smoke.yaml").read_text())
    cfg["results"] = str(smoke_pipeline)
    path = tmp_path / "smoke.yaml"
    path.write_text(yaml.safe_dump(cfg))
    before = sorted(p for p in smoke_pipeline.rglob("*"))
    cmd = [sys.executable, "-m", "frng", "bench", "train", "--config", str(path), "--threads", "1", "--bf16", "off"]
    r = subprocess.run(
        [*cmd, "--steps", "2", "--skip", "1", "--objects", "1", "--json"],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert r.returncode == 0, r.stderr[-2000:]
    rows = [json.loads(line) for line in r.stdout.splitlines()]
    assert [(x["model"], x["threads"], x["bf16"]) for x in rows] == [("backbone", 1, "off"), ("frng", 1, "off")]
    assert all(x["step_ms"] > 0 and x["step_ms_mean"] > 0 and x["steps"] == 2 and x["speedup"] == 1.0 for x in rows)
    assert sorted(p for p in smoke_pipeline.rglob("*")) == before  # nothing written under the results folder
