"""Helpers shared by the dataset tests: tiny configs and running stages through the CLI (as the rules do)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import yaml


def write_config(path: Path, results: Path, **sections) -> Path:
    """A tiny valid config (16-32 px, few spp) with ``sections`` merged over the defaults below."""
    cfg = {
        "tier": "custom",
        "seed": 0,
        "results": str(results),
        "objects": {"count": 2, "test_count": 1, "sources": ["primitives"]},
        "envmaps": {
            "width": 32,
            "bundled": ["studio", "city", "forest"],
            "skies": {"models": []},
            "rotations": 1,
            "test_fraction": 0.34,
        },
        "render": {
            "resolution": 32,
            "spp": 4,
            "extra_input_views": 0,
            "target_views": 2,
            "input_lights": 1,
            "target_lights": 1,
            "fur_strands": 200,
        },
    }
    for key, value in sections.items():
        cfg[key] = {**cfg.get(key, {}), **value} if isinstance(value, dict) else value
    path.write_text(yaml.safe_dump(cfg))
    return path


def frng(*args: str, check: bool = True) -> subprocess.CompletedProcess:
    proc = subprocess.run([sys.executable, "-m", "frng", *args], capture_output=True, text=True, timeout=300)
    if check and proc.returncode != 0:
        raise AssertionError(f"frng {' '.join(args)} failed ({proc.returncode}):\n{proc.stdout}\n{proc.stderr}")
    return proc


def kill_at_first_checkpoint(cmd: list[str], out: Path) -> int:
    """Start a training command, SIGKILL its process group as soon as ``out/checkpoint.pt`` exists (at most 120 s),
    check that no model was written, and return the checkpoint's step."""
    import os
    import signal
    import time

    import torch

    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
    ckpt = out / "checkpoint.pt"
    deadline = time.time() + 120
    while not ckpt.exists() and time.time() < deadline and proc.poll() is None:
        time.sleep(0.2)
    os.killpg(proc.pid, signal.SIGKILL)
    proc.wait()
    assert ckpt.exists() and not (out / "model.pt").exists()
    return torch.load(ckpt, weights_only=False)["step"]


def protocol_scores(
    psnr: float, ssim: float = 0.5, lpips: float = 0.1, scale=(1.0, 1.0, 1.0), brightness=None, interior=None
) -> dict:
    """The score columns of a per-image metrics row (frng.metrics): psnr, ssim, lpips, the aligned protocol's per-channel
    ``scale_*``, unless ``brightness`` is None the ``brightness_*`` ratios, unless ``interior`` is None
    ``psnr_interior``."""
    row = dict(psnr=psnr, ssim=ssim, lpips=lpips, **{f"scale_{c}": float(v) for c, v in zip("rgb", scale)})
    if interior is not None:
        row["psnr_interior"] = float(interior)
    if brightness is not None:
        row.update({f"brightness_{c}": float(v) for c, v in zip("rgb", brightness)})
    return row
