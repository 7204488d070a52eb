"""Torch-free stages stay torch-free (frng.lazytorch): importing curation's modules does not import torch, and the
modules that import torch lazily still give torch's results (dtypes of their defaults included)."""

import subprocess
import sys

import torch

from frng import camera
from frng.render import envmap

TORCH_FREE = [
    "frng.cli",
    "frng.stages.curate",
    "frng.data.curate",
    "frng.plan.catalog",
    "frng.data.envmaps",
    "frng.data.rig",
    "frng.camera",
    "frng.render.envmap",
    "frng.plan.variants",
]


def test_curation_modules_do_not_import_torch():
    code = "import sys\n" + "".join(f"import {m}\n" for m in TORCH_FREE) + "print('torch' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "False"


def test_lazily_imported_torch_keeps_defaults_and_results():
    assert camera.pixel_centers(2, 3).dtype == torch.float32
    assert camera.pixel_centers(2, 3)[1, 2].tolist() == [2.5, 1.5]
    assert envmap.pixel_directions(4, 8).dtype == torch.float32
    omega = envmap.pixel_solid_angles(4, 8)
    assert omega.dtype == torch.float64 and abs(float(omega.sum()) - 4 * torch.pi) < 1e-9
    assert isinstance(envmap.pixel_uv(2, 4)[0], torch.Tensor)
