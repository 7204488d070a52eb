"""`frng bench render --json` and `frng bench perceptual --json` print one JSON object per configuration with the
documented keys."""

import json
import subprocess

from conftest import venv_bin


def bench_rows(*args: str) -> list[dict]:
    """The JSON rows `frng bench ARGS --json` prints. The timeout only guards against a hang: ~6 s alone, it passed
    120 s in a niced `make test` beside three trainings (2026-11-28)."""
    out = subprocess.run(
        [venv_bin("frng"), "bench", *args, "--json"], capture_output=True, text=True, check=True, timeout=600
    ).stdout
    return [json.loads(line) for line in out.splitlines() if line.strip()]


def test_bench_render_json():
    rows = bench_rows("render", "--sizes", "16", "--channels", "3", "8", "--repeats", "1")
    assert [r["channels"] for r in rows] == [3, 8]
    for r in rows:
        for key in ["backend", "size", "views", "gaussians", "channels", "fwd_ms", "fwd_bwd_ms", "peak_mb"]:
            assert key in r
        assert r["gaussians"] == 6 * 16 * 16 and r["fwd_ms"] > 0 and r["fwd_bwd_ms"] > 0
    assert rows[-1]["shade_infer_ms_per_image"] > 0


def test_bench_perceptual_json():
    """`frng bench perceptual --json`: one row per (net, size, batch) with a positive time."""
    rows = bench_rows(
        "perceptual", "--nets", "alex", "--sizes", "32", "--batches", "1", "2", "--repeats", "1", "--threads", "1"
    )
    assert [(r["net"], r["size"], r["batch"]) for r in rows] == [("alex", 32, 1), ("alex", 32, 2)]
    assert all(r["fwd_bwd_ms"] > 0 and r["threads"] == 1 for r in rows)
