"""Stage ``frng envmaps``: prepare every environment map of the dataset plan.

For each base map of :func:`frng.data.catalog.envmap_plan` -- one of Blender's 8 bundled CC0 HDRIs, a
Preetham / Hosek-Wilkie sky baked with Cycles (lower hemisphere darkened to a 0.3-albedo ground), or a
user's EXR/HDR file -- and each of its ``envmaps.rotations`` random Z rotations:

    rotate (frng.envmap.rotate_z, at the source resolution) -> resize to envmaps.width (frng.envmap.resize)
    -> scale so the solid-angle-weighted mean luminance is envmaps.normalize (if set) -> write

Outputs (``--out``, default ``{results}/envmaps``):

    {name}.exr    linear float32 RGB equirect, width = envmaps.width, height = width / 2
    {name}.json   the map's record (as in the index)
    index.json    {"width", "height", "normalize", "maps": [record, ...]}; a record has name, base, source,
                  split, rotation_deg, licence, origin, sky, scale (applied factor), mean_luminance (after).
"""

from __future__ import annotations

import argparse
import math
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from frng import config as frng_config
from frng import envmap, io
from frng.data import catalog

SKY_BAKE_WIDTH = 512  # skies are smooth; baked at this width then resized
GROUND_ALBEDO = 0.3


def mean_luminance(image: np.ndarray) -> float:
    """Solid-angle-weighted mean luminance of an equirect map (H, W, 3): (1/4pi) * integral of L dOmega."""
    h, w = image.shape[:2]
    omega = envmap.pixel_solid_angles(h, w).numpy()
    return float((envmap.luminance(image) * omega).sum() / (4.0 * math.pi))


def bundled_dir() -> Path:
    import bpy

    return Path(bpy.utils.system_resource("DATAFILES", path="studiolights/world"))


def load_base(spec: catalog.EnvMapSpec, work: Path, threads: int) -> np.ndarray:
    """The base map of ``spec`` at its source resolution, linear float32 (H, W, 3)."""
    if spec.source == "bundled":
        return envmap.read(bundled_dir() / spec.origin)
    if spec.source == "user":
        return envmap.read(spec.origin)
    if spec.source == "sky":
        from frng.blender import scene as bscene
        from frng.blender import world

        sky = spec.sky
        path = work / f"{spec.base}.exr"
        world.bake_sky(path, sky["model"], sky["sun_elevation_deg"], sky["turbidity"], SKY_BAKE_WIDTH,
                       threads=threads)
        rgb = bscene.read_passes(path)["rgba"][..., :3]
        return world.ground(np.maximum(rgb, 0.0), GROUND_ALBEDO)
    raise ValueError(f"unknown env-map source {spec.source!r}")


def prepare(config: dict, out: Path, log=print) -> list[dict]:
    """Write every planned map into ``out`` (see the module docstring). Returns the index records."""
    env = config["envmaps"]
    specs = catalog.envmap_plan(config)
    out.mkdir(parents=True, exist_ok=True)
    records: list[dict] = []
    bases: dict[str, np.ndarray] = {}
    threads = config["render"]["threads"]
    with tempfile.TemporaryDirectory(prefix=".tmp-bake-", dir=out) as work:
        for spec in specs:
            t0 = time.perf_counter()
            if spec.base not in bases:
                bases.clear()  # keep one base in memory
                bases[spec.base] = load_base(spec, Path(work), threads)
            img = envmap.resize(envmap.rotate_z(bases[spec.base], spec.rotation_deg), env["width"])
            raw = mean_luminance(img)
            if raw <= 0.0:
                raise envmap.EnvMapError(f"{spec.origin}: environment map {spec.name} is black (mean luminance 0)")
            scale = 1.0 if env["normalize"] is None else float(env["normalize"]) / raw
            img = img * np.float32(scale)
            rec = spec.to_dict() | {"scale": scale, "mean_luminance": mean_luminance(img),
                                    "file": f"{spec.name}.exr"}
            envmap.write(out / f"{spec.name}.exr", img)
            io.write_json(out / f"{spec.name}.json", rec)
            records.append(rec)
            log(f"[envmaps] {spec.name:<32} {spec.split:<5} rot {spec.rotation_deg:7.2f} deg  "
                f"scale {scale:9.4f}  {time.perf_counter() - t0:.2f} s")
    io.write_json(out / "index.json", {"width": env["width"], "height": env["width"] // 2,
                                       "normalize": env["normalize"], "maps": records})
    return records


def read_index(path: str | Path) -> dict:
    """The env-map index (``index.json``) with a clear error when it is missing or malformed."""
    path = Path(path)
    try:
        index = io.read_json(path)
    except (FileNotFoundError, ValueError) as e:
        raise envmap.EnvMapError(f"{path}: cannot read the env-map index ({e}); run `frng envmaps` first") from e
    if "maps" not in index:
        raise envmap.EnvMapError(f"{path}: env-map index has no 'maps' key")
    return index


# -- CLI ------------------------------------------------------------------------------------------------

def configure(parser: argparse.ArgumentParser) -> None:
    frng_config.add_config_argument(parser)
    parser.add_argument("--out", help="output folder (default: {results}/envmaps)")


def run(args: argparse.Namespace) -> int:
    config = frng_config.load(args.config)
    out = Path(args.out) if args.out else Path(config["results"]) / "envmaps"
    t0 = time.perf_counter()
    try:
        records = prepare(config, out, log=lambda m: print(m, flush=True))
    except (envmap.EnvMapError, catalog.CatalogError, io.ImageError) as e:
        print(f"frng envmaps: error: {e}", file=sys.stderr)
        return 1
    n_test = sum(r["split"] == "test" for r in records)
    print(f"[envmaps] wrote {len(records)} maps ({len(records) - n_test} train, {n_test} test) to {out} "
          f"in {time.perf_counter() - t0:.1f} s", flush=True)
    return 0
