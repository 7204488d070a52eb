"""Caches and asset decoders are written with a canonical safetensors header (frng.io.save_safetensors): the
library writes its metadata dict in a random order per process, so the same tensors used to give files with
different bytes (and sha256) from run to run."""

import subprocess
import sys

import torch
from safetensors import safe_open

from frng import io

SCRIPT = """
import sys, torch
from frng import io
t = {"b": torch.arange(6, dtype=torch.float32).reshape(2, 3), "a": torch.ones(4, dtype=torch.int64)}
meta = {k: f"value-{k}-\u00e9" for k in ("version", "model_sha256", "input_light", "lights", "view_names", "zeta")}
io.save_safetensors(t, sys.argv[1], meta)
"""


def test_same_tensors_same_bytes_across_processes(tmp_path):
    paths = [tmp_path / f"c{i}.safetensors" for i in range(3)]
    for p in paths:
        subprocess.run([sys.executable, "-c", SCRIPT, str(p)], check=True)
    data = [p.read_bytes() for p in paths]
    assert data[0] == data[1] == data[2]
    with safe_open(str(paths[0]), framework="pt") as f:
        assert f.metadata()["input_light"] == "value-input_light-\u00e9"
        assert torch.equal(f.get_tensor("b"), torch.arange(6, dtype=torch.float32).reshape(2, 3))


def test_failed_write_leaves_no_file(tmp_path):
    bad = {"x": torch.zeros(2)}
    out = tmp_path / "x.safetensors"
    try:
        io.save_safetensors(bad, out, {"k": 3})  # metadata values must be strings
    except Exception:  # noqa: BLE001
        pass
    assert not out.exists() and not list(tmp_path.glob(".tmp-*"))
