"""`frng bench render --json` prints one JSON object per configuration with the documented keys."""

import json
import subprocess

from conftest import venv_bin


def test_bench_render_json():
    out = subprocess.run(
        [venv_bin("frng"), "bench", "render", "--sizes", "16", "--channels", "3", "8", "--repeats", "1", "--json"],
        capture_output=True,
        text=True,
        check=True,
        timeout=120,
    ).stdout
    rows = [json.loads(line) for line in out.splitlines() if line.strip()]
    assert [r["channels"] for r in rows] == [3, 8]
    for r in rows:
        for key in ["backend", "size", "views", "gaussians", "channels", "fwd_ms", "fwd_bwd_ms", "peak_mb"]:
            assert key in r
        assert r["gaussians"] == 6 * 16 * 16 and r["fwd_ms"] > 0 and r["fwd_bwd_ms"] > 0
    assert rows[-1]["shade_infer_ms_per_image"] > 0
