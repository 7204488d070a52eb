"""Every environment map of the dataset plan (stage :mod:`frng.stages.envmaps`, ``frng envmaps``).

For each (object, light) draw of :func:`frng.plan.catalog.envmap_plan` -- a rotated copy of a base map of the light
pool (:func:`frng.plan.catalog.light_bases`): one of Blender's 8 bundled CC0 HDRIs, a Preetham / Hosek-Wilkie sky
baked with Cycles (lower hemisphere darkened to a 0.3-albedo ground; a sun disc added, :func:`add_sun`), a procedural studio (:func:`studio_map`: seeded
area lights over a dim or dark background, baked at 512 px) or a user's EXR/HDR file:

    load the base once (resized to ROTATE_OVERSAMPLE x envmaps.width where the source is wider)
    -> rotate by the draw's angle (frng.render.envmap.rotate_z) -> resize to envmaps.width (frng.render.envmap.resize)
    -> scale so the solid-angle-weighted mean luminance is envmaps.normalize (if set) -> write

Outputs (``--out``, default ``{results}/envmaps``):

    {name}.exr    linear float32 RGB equirect, width = envmaps.width, height = width / 2
    {name}.json   the map's record (as in the index)
    index.json    {"width", "height", "normalize", "maps": [record, ...]}; a record has name, base, source,
                  split, rotation_deg, licence, origin, sky, family, hard, object (the draw's), scale
                  (applied factor), mean_luminance (after), hardness (:func:`hardness`, measured).

All or nothing (see :func:`prepare`): a failed or killed run leaves no record without its map.
"""

from __future__ import annotations

import math
import os
import shutil
import tempfile
import time
from pathlib import Path

import numpy as np

from frng import io
from frng.data.stopguard import NoGuard
from frng.plan import catalog, dataset_config
from frng.plan.layout import EnvmapFolder
from frng.render import envmap

SKY_BAKE_WIDTH = 512  # skies are smooth; baked at this width then resized
GROUND_ALBEDO = 0.3
SUN_DIAMETER_DEG = 0.53  # the sun's angular diameter (drawn at least 2 pixels across)
ROTATE_OVERSAMPLE = 4  # each draw is rotated at this many times the output width (at most the source's), then resized
HARD_SOLID_ANGLE = 0.01  # hardness: the share of the light arriving from the brightest 1 % of the sphere


def mean_luminance(image: np.ndarray) -> float:
    """Solid-angle-weighted mean luminance of an equirect map (H, W, 3): (1/4pi) * integral of L dOmega."""
    h, w = image.shape[:2]
    omega = envmap.pixel_solid_angles(h, w).numpy()
    return float((envmap.luminance(image) * omega).sum() / (4.0 * math.pi))


def hardness(image: np.ndarray, share: float = HARD_SOLID_ANGLE) -> float:
    """How hard a light is: the fraction of the map's energy (solid-angle-weighted luminance) that arrives from its
    brightest pixels covering ``share`` of the sphere (1 % by default). A uniform map gives ``share``, a single
    small light ~1; the procedural hard studios, whose key light covers a few square degrees, come near 1."""
    h, w = image.shape[:2]
    omega = envmap.pixel_solid_angles(h, w).numpy().ravel()
    lum = np.maximum(envmap.luminance(image), 0.0).ravel()
    order = np.argsort(-lum, kind="stable")
    energy = (lum * omega)[order]
    total = float(energy.sum())
    if total <= 0.0:
        return float("nan")
    covered = np.cumsum(omega[order]) <= share * 4.0 * math.pi
    return float(energy[covered].sum() / total)


def add_sun(
    image: np.ndarray, elevation_deg: float, share: float, diameter_deg: float = SUN_DIAMETER_DEG
) -> np.ndarray:
    """A sky map (H, W, 3) plus a sun disc towards +X at ``elevation_deg`` (Blender's sky bake puts its sun there)
    that carries ``share`` (< 1) of the result's light (solid-angle-weighted luminance), in the sky's own colour at
    the sun's direction (luminance 1: warm low suns). Blender's Preetham / Hosek-Wilkie skies have no sun disc;
    on a clear day the sun brings ~0.8 of the light. The disc is ``diameter_deg`` wide but at least 2 pixels
    across, its edge softened over a pixel."""
    import torch

    if not 0.0 <= share < 1.0:
        raise ValueError(f"sun share {share} is not in [0, 1)")
    h, w = image.shape[:2]
    d = envmap.pixel_directions(h, w, dtype=torch.float64).numpy()
    el = math.radians(elevation_deg)
    sun = np.array([math.cos(el), 0.0, math.sin(el)])
    pixel = math.pi / h
    radius = max(math.radians(diameter_deg) / 2.0, pixel)
    mask = np.clip((radius - np.arccos(np.clip(d @ sun, -1.0, 1.0))) / pixel + 0.5, 0.0, 1.0)
    omega = envmap.pixel_solid_angles(h, w).numpy()
    e_sky = float((envmap.luminance(image) * omega).sum())
    e_disc = float((mask * omega).sum())
    j, i = np.unravel_index(np.argmax(d @ sun), (h, w))
    colour = np.maximum(image[j, i, :3].astype(np.float64), 0.0)
    lum = float(envmap.luminance(colour))
    colour = colour / lum if lum > 0 else np.ones(3)
    radiance = share / (1.0 - share) * e_sky / e_disc
    return (image + mask[..., None] * radiance * colour).astype(np.float32)


def bundled_dir() -> Path:
    import bpy

    return Path(bpy.utils.system_resource("DATAFILES", path="studiolights/world"))


def _lobe(lam: np.ndarray, mu: float, s1: float, s2: float) -> np.ndarray:
    s = np.where(lam < mu, s1, s2)
    return np.exp(-0.5 * ((lam - mu) / s) ** 2)


def blackbody_rgb(kelvin: float) -> np.ndarray:
    """Linear Rec. 709 colour (3,) of a blackbody at ``kelvin``, luminance 1: Planck's law integrated against the
    CIE 1931 colour-matching functions (the multi-lobe fit of Wyman, Sloan and Shirley 2013), XYZ -> linear sRGB,
    negatives clipped. 6500 K is near white, 2700 K orange, 10000 K blue."""
    lam = np.arange(380.0, 781.0, 5.0)
    x = (
        1.056 * _lobe(lam, 599.8, 37.9, 31.0)
        + 0.362 * _lobe(lam, 442.0, 16.0, 26.7)
        - 0.065 * _lobe(lam, 501.1, 20.4, 26.2)
    )
    y = 0.821 * _lobe(lam, 568.8, 46.9, 40.5) + 0.286 * _lobe(lam, 530.9, 16.3, 31.1)
    z = 1.217 * _lobe(lam, 437.0, 11.8, 36.0) + 0.681 * _lobe(lam, 459.0, 26.0, 13.8)
    m = lam * 1e-9
    planck = 1.0 / (m**5 * (np.exp(1.4388e-2 / (m * float(kelvin))) - 1.0))
    xyz = np.array([(x * planck).sum(), (y * planck).sum(), (z * planck).sum()])
    rgb = np.array([[3.2406, -1.5372, -0.4986], [-0.9689, 1.8758, 0.0415], [0.0557, -0.2040, 1.0570]]) @ xyz
    rgb = np.maximum(rgb, 0.0)
    return (rgb / envmap.luminance(rgb)).astype(np.float32)


def studio_map(params: dict, width: int) -> np.ndarray:
    """A procedural studio (``catalog.studio_params``) as a linear equirect map (width/2, width, 3), frng.render.envmap's
    convention: a dim or dark background (``background`` above the horizon, half of it below: a floor) plus rectangular
    area lights facing the origin, each of radiance ``strength`` x its blackbody colour, edges softened over 5% of
    their size (and at least a pixel)."""
    h = width // 2
    d = envmap.pixel_directions(h, width, dtype=__import__("torch").float64).numpy()
    bg = float(params["background"])
    img = np.where(d[..., 2:3] >= 0.0, bg, 0.5 * bg) * np.ones(3)
    pixel = math.pi / h
    for light in params["lights"]:
        az, el = math.radians(light["azimuth_deg"]), math.radians(light["elevation_deg"])
        f = np.array([math.cos(el) * math.cos(az), math.cos(el) * math.sin(az), math.sin(el)])
        r = np.cross(f, [0.0, 0.0, 1.0])
        r = r / np.linalg.norm(r) if np.linalg.norm(r) > 1e-6 else np.array([1.0, 0.0, 0.0])
        u = np.cross(r, f)
        roll = math.radians(light["roll_deg"])
        r, u = math.cos(roll) * r + math.sin(roll) * u, -math.sin(roll) * r + math.cos(roll) * u
        a = d @ f
        x, y = np.arctan2(d @ r, a), np.arctan2(d @ u, a)
        hw, hh = math.radians(light["width_deg"]) / 2, math.radians(light["height_deg"]) / 2
        soft_x, soft_y = max(pixel, 0.1 * hw), max(pixel, 0.1 * hh)
        mask = np.clip((hw - np.abs(x)) / soft_x + 0.5, 0, 1) * np.clip((hh - np.abs(y)) / soft_y + 0.5, 0, 1) * (a > 0)
        img = img + mask[..., None] * float(light["strength"]) * blackbody_rgb(light["kelvin"])
    return img.astype(np.float32)


def load_base(spec: catalog.EnvMapSpec, work: Path, threads: int) -> np.ndarray:
    """The base map of ``spec`` at its source resolution, linear float32 (H, W, 3)."""
    if spec.source == "studio":
        return studio_map(spec.studio, SKY_BAKE_WIDTH)
    if spec.source == "bundled":
        return envmap.read(bundled_dir() / spec.origin)
    if spec.source == "user":
        return envmap.read(spec.origin)
    if spec.source == "sky":
        from frng.blender import scene as bscene
        from frng.blender import world

        sky = spec.sky
        path = work / f"{spec.base}.exr"
        world.bake_sky(path, sky["model"], sky["sun_elevation_deg"], sky["turbidity"], SKY_BAKE_WIDTH, threads=threads)
        rgb = bscene.read_passes(path)["rgba"][..., :3]
        img = world.ground(np.maximum(rgb, 0.0), GROUND_ALBEDO)
        share = float(sky.get("sun_share", 0.0))
        return add_sun(img, sky["sun_elevation_deg"], share) if share > 0 else img
    raise ValueError(f"unknown env-map source {spec.source!r}")


def prepare(
    env: dataset_config.EnvmapsConfig,
    specs: list[catalog.EnvMapSpec],
    threads: int,
    out: Path,
    log=print,
    guard=None,
) -> list[dict]:
    """Write every planned map ``specs`` (:func:`frng.plan.catalog.envmap_plan`) into ``out`` (see the module
    docstring), ``env`` the config's ``envmaps`` section, ``threads`` its ``render.threads`` (Blender's, for the
    skies). Returns the index records.

    All-or-nothing: the maps and records are written into a staging folder ``out/.tmp-envmaps-*`` and moved into
    place only once every map succeeded, each EXR before its record, the index last -- so a failed or killed run
    never leaves a record without its map (nor a half-written map). Records whose map is missing (left by older
    runs, or by Snakemake deleting a failed job's maps) and staging folders of killed runs are removed first.
    ``guard``: a :class:`frng.data.stopguard.StopGuard` that removes the staging folder on SIGINT/SIGTERM.
    """
    guard = guard or NoGuard()
    out.mkdir(parents=True, exist_ok=True)
    remove_stale(out, log)
    records: list[dict] = []
    bases: dict[str, np.ndarray] = {}
    with guard.lock:
        staging = io.temp_dir(".tmp-envmaps-", out)
        guard.paths.append(staging)
        staged, final = EnvmapFolder(staging), EnvmapFolder(out)
        work = Path(tempfile.mkdtemp(prefix="frng-envmaps-bake-"))  # Blender renders skies here
        guard.paths.append(work)
    try:
        for spec in specs:
            t0 = time.perf_counter()
            if spec.base not in bases:
                bases.clear()  # keep one base in memory (the plan orders the draws by base)
                base = load_base(spec, work, threads)
                if base.shape[1] > ROTATE_OVERSAMPLE * env.width:
                    base = envmap.resize(base, ROTATE_OVERSAMPLE * env.width)
                bases[spec.base] = base
            img = envmap.resize(envmap.rotate_z(bases[spec.base], spec.rotation_deg), env.width)
            raw = mean_luminance(img)
            if not np.isfinite(raw) or raw <= 0.0:
                raise envmap.EnvMapError(
                    f"{spec.origin}: environment map {spec.name} is black or not finite (mean luminance {raw})"
                )
            scale = 1.0 if env.normalize is None else float(env.normalize) / raw
            img = img * np.float32(scale)
            rec = spec.to_dict() | {
                "scale": scale,
                "mean_luminance": mean_luminance(img),
                "hardness": round(hardness(img), 4),
                "file": EnvmapFolder(".").envmap(spec.name),
            }
            with guard.lock:
                envmap.write(staged.envmap(spec.name), img)
                io.write_json(staged.record(spec.name), rec)
            records.append(rec)
            log(
                f"[envmaps] {spec.name:<44} {spec.split:<5} {spec.family:<6} rot {spec.rotation_deg:7.2f} deg  "
                f"scale {scale:9.4f}  hardness {rec['hardness']:.3f}  {time.perf_counter() - t0:.2f} s"
            )
        with guard.lock:
            io.write_json(
                staged.index(),
                {"width": env.width, "height": env.width // 2, "normalize": env.normalize, "maps": records},
            )
            for rec in records:  # the map first: a record never exists without it
                name = rec["name"]
                os.replace(staged.envmap(name), final.envmap(name))
                os.replace(staged.record(name), final.record(name))
            os.replace(staged.index(), final.index())
    finally:
        with guard.lock:
            for path in (staging, work):
                shutil.rmtree(path, ignore_errors=True)
    return records


def remove_stale(out: Path, log=print) -> None:
    """Remove what an earlier failed or killed run left in ``out``: staging folders and temporary files
    (``.tmp-*``; only one env-map job writes a results folder at a time) and records ``{name}.json`` whose map
    ``{name}.exr`` is missing."""
    for p in sorted(out.glob(".tmp-*")):
        log(f"[envmaps] removing {p.name}, left by an earlier run that failed or was killed")
        shutil.rmtree(p, ignore_errors=True) if p.is_dir() else p.unlink(missing_ok=True)
    for rec in sorted(out.glob("*.json")):
        if str(rec) != EnvmapFolder(out).index() and not rec.with_suffix(".exr").exists():
            log(f"[envmaps] removing {rec.name}: its map {rec.with_suffix('.exr').name} is missing")
            rec.unlink(missing_ok=True)


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
