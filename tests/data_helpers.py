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
