"""CUDA checks (marker ``gpu``; skipped where there is no CUDA): what runs on a CPU cannot catch, e.g. a CUDA
generator handed to a CPU op. Where a GPU is lent: ``pytest -m gpu`` (docs/performance.md "On a GPU")."""

import subprocess
import sys

import pytest
import torch
from test_render_shading import random_ggx_pixels

from frng.render.envmap import EnvSamples
from frng.render.shading import CUDA_CHUNK_SCALE, ggx_reflectance, shade_pixels

pytestmark = [pytest.mark.gpu, pytest.mark.skipif(not torch.cuda.is_available(), reason="needs CUDA")]


def test_relighting_runs_on_cuda(root):
    """Reconstruction, the backbone's relighting, rasterization and F-RNG's shading with CUDA generators, at the
    smoke config's sizes (``frng bench relight --device cuda``)."""
    cmd = [sys.executable, "-m", "frng", "bench", "relight", "--configs", "config/smoke.yaml", "--resolution", "24"]
    r = subprocess.run(
        cmd + ["--passes", "1", "--device", "cuda"], cwd=root, capture_output=True, text=True, timeout=900
    )
    assert r.returncode == 0, r.stdout[-2000:] + r.stderr[-3000:]
    assert "on cuda" in r.stdout, r.stdout[-2000:]


def test_shading_on_cuda_matches_cpu():
    """The Monte-Carlo estimate at CUDA's chunk sizes (x CUDA_CHUNK_SCALE) equals the CPU's, float64."""
    P, K = 3 * CUDA_CHUNK_SCALE + 5, 40
    wo, params = random_ggx_pixels(P, seed=0)
    g = torch.Generator().manual_seed(1)
    dt = torch.float64
    dirs = torch.nn.functional.normalize(torch.randn(K, 3, generator=g, dtype=dt), dim=-1)
    radiance = torch.rand(K, 3, generator=g, dtype=dt)
    samples = EnvSamples(dirs=dirs, pdf=torch.full((K,), 1 / (4 * torch.pi), dtype=dt), radiance=radiance)
    cpu = shade_pixels(ggx_reflectance, params, wo, samples, chunk=7, chunk_pairs=64)
    cuda_samples = EnvSamples(*(t.cuda() for t in samples))
    gpu = shade_pixels(ggx_reflectance, [p.cuda() for p in params], wo.cuda(), cuda_samples, chunk=7, chunk_pairs=64)
    assert torch.allclose(gpu.cpu(), cpu, atol=1e-10), (gpu.cpu() - cpu).abs().max()
