"""Curation (stage :mod:`frng.stages.curate`, ``frng curate``): ONE Blender process renders ONE object's whole set.

For object ``{obj}`` (``--object``) it writes ``{results}/objects/{obj}/``:

    inputs/{light}/{view}.exr    input views (in_00 ..) under each input light: RGBA float32, linear,
                                 premultiplied alpha (alpha = coverage = object mask)
    targets/{light}/{view}.exr   target views (tgt_000 ..) under each target light, same format
    gbuffer/{view}.exr           one G-buffer per view (input and target views), light independent
    meta.json                    cameras, lights, material, mesh source, licence, seed, render times

G-buffer EXR channels (float32, same size as the renders; see config/README.md):

    A                    coverage (alpha of the render)
    normal.X/Y/Z         world-space unit normal (Z up); 0 where A == 0
    depth.Z              distance along the camera's optical axis (OpenCV camera z), world units; 0 where A == 0
    albedo.R/G/B         linear base colour (texture value where textured; hair colour on fur strands)
    roughness.Y          Principled roughness in [0, 1]
    metallic.Y           Principled metallic in [0, 1]

Normals, albedo, roughness and metallic are divided by A (un-premultiplied) where A > 0, so edge pixels hold
the surface's value, not a blend with the empty background.

Everything is written into ``objects/.tmp-{obj}-*`` and renamed to ``objects/{obj}`` at the end, so a failed
job (mesh that does not load, empty render, corrupt env map) leaves nothing that looks valid. SIGINT (Ctrl-C) and
SIGTERM (scancel, a killed job) stop the job at once, also mid-render (:class:`StopGuard`), remove the staging
folder and exit 130 / 143; staging folders of the same object left by a SIGKILLed job are removed when its
curation starts.
"""

from __future__ import annotations

import contextlib
import re
import shutil
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from frng import io
from frng.data import rig
from frng.data.envmaps import read_index
from frng.data.stopguard import NoGuard, StopGuard
from frng.plan import catalog, dataset_config, object_files
from frng.plan.layout import EnvmapFolder, Layout, ObjectFolder
from frng.render import envmap

GBUFFER_CHANNELS = (
    "A",
    "normal.X",
    "normal.Y",
    "normal.Z",
    "depth.Z",
    "albedo.R",
    "albedo.G",
    "albedo.B",
    "roughness.Y",
    "metallic.Y",
)
META_VERSION = 1
RENDER_META_KEYS = (  # the render.* settings meta.json records
    "resolution",
    "spp",
    "denoise",
    "denoise_prefilter",
    "clamp_direct",
    "clamp_indirect",
    "camera_distance",
    "fov_deg",
    "threads",
)


class CurationError(RuntimeError):
    """Curation of one object failed; the message names the object and file."""


def stale_temp_dirs(out_root: Path, oid: str) -> list[Path]:
    """Staging folders ``.tmp-{oid}-XXXXXXXX`` of object ``oid`` (never another object's, even one whose id
    starts with ``oid``) that a killed curation left behind."""
    if not out_root.is_dir():
        return []
    pattern = re.compile(rf"\.tmp-{re.escape(oid)}-[a-z0-9_]{{8}}")
    return sorted(d for d in out_root.iterdir() if pattern.fullmatch(d.name) and d.is_dir())


@dataclass(frozen=True)
class StagedObject:
    """An object folder being written (:func:`staged_object`): ``folder`` (the staging folder), ``scratch`` (Blender's
    render folder), ``final`` (where :meth:`commit` renames it)."""

    folder: ObjectFolder
    scratch: Path
    final: Path
    guard: StopGuard | NoGuard

    def commit(self, meta: dict) -> None:
        """Write ``meta.json`` (the file that marks the object complete) and swap the folder into place."""
        with self.guard.lock:
            io.write_json(self.folder.meta(), meta)
            if self.final.exists():
                shutil.rmtree(self.final)
            self.folder.root.rename(self.final)


@contextlib.contextmanager
def staged_object(out_root: Path, oid: str, guard, log) -> Iterator[StagedObject]:
    """Stage object ``oid``'s folder ``out_root/oid``: removes staging folders a SIGKILLed run of it left (only one
    runs at a time), makes ``.tmp-{oid}-*`` folders for the files and for Blender's renders (a render that finishes
    while the guard removes the staging folder cannot create that folder again) under ``guard``, and removes both when
    the block ends; :meth:`StagedObject.commit` swaps the files into place. A failed job leaves nothing that looks
    valid."""
    out_root.mkdir(parents=True, exist_ok=True)
    for stale in stale_temp_dirs(out_root, oid):
        log(f"[{oid}] removing {stale.name}, left by an earlier run that was killed")
        shutil.rmtree(stale, ignore_errors=True)
    with guard.lock:
        tmp = io.temp_dir(f".tmp-{oid}-", out_root)
        guard.paths.append(tmp)
        scratch = io.temp_dir(f".tmp-{oid}-", out_root)
        guard.paths.append(scratch)
    try:
        yield StagedObject(ObjectFolder(tmp), scratch, out_root / oid, guard)
    finally:
        with guard.lock:
            for path in (tmp, scratch):
                shutil.rmtree(path, ignore_errors=True)


def gbuffer_from_passes(passes: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """Rendered passes -> G-buffer channel planes (H, W) named as in :data:`GBUFFER_CHANNELS`."""
    a = passes["rgba"][..., 3]
    hit = a > 1e-4
    inv = np.where(hit, 1.0 / np.maximum(a, 1e-4), 0.0).astype(np.float32)[..., None]
    normal = passes["normal"] * inv
    length = np.linalg.norm(normal, axis=-1, keepdims=True)
    normal = np.where(length > 1e-6, normal / np.maximum(length, 1e-6), 0.0)
    depth = np.where(hit & (passes["depth"][..., 0] < 1e9), passes["depth"][..., 0], 0.0)
    albedo = np.clip(passes["albedo"] * inv, 0.0, None)
    rough = np.clip(passes["roughness"][..., 0] * inv[..., 0], 0.0, 1.0)
    metal = np.clip(passes["metallic"][..., 0] * inv[..., 0], 0.0, 1.0)
    planes = {
        "A": a,
        "normal.X": normal[..., 0],
        "normal.Y": normal[..., 1],
        "normal.Z": normal[..., 2],
        "depth.Z": depth,
        "albedo.R": albedo[..., 0],
        "albedo.G": albedo[..., 1],
        "albedo.B": albedo[..., 2],
        "roughness.Y": rough,
        "metallic.Y": metal,
    }
    return {k: planes[k].astype(np.float32) for k in GBUFFER_CHANNELS}


def own_class(spec: catalog.ObjectSpec, folder: ObjectFolder, views) -> tuple[str, str]:
    """(class, how it was chosen) of an own material: the config's ``class``, else
    :func:`frng.plan.object_files.own_material_class` of the mean roughness / metallic AOVs over the foreground
    (coverage > 0.5) of the input views' G-buffers."""
    if spec.material_class is not None:
        return spec.material_class, "from the config (objects.extra[].class)"
    rough, metal = [], []
    for view in views:
        ch = io.read_exr_channels(folder.gbuffer(view.name))
        fg = ch["A"] > 0.5
        rough.append(ch["roughness.Y"][fg])
        metal.append(ch["metallic.Y"][fg])
    r, m = float(np.concatenate(rough).mean()), float(np.concatenate(metal).mean())
    return object_files.own_material_class(r, m), (
        f"mean roughness {r:.3f}, metallic {m:.3f}: specular if metallic >= "
        f"{object_files.OWN_SPECULAR_METALLIC} or roughness < "
        f"{object_files.OWN_SPECULAR_ROUGHNESS}, else diffuse"
    )


def check_envmaps(spec: catalog.ObjectSpec, env_dir: Path) -> dict[str, dict]:
    """Every light of the object exists, is readable and is in the index; returns index records by name."""
    folder = EnvmapFolder(env_dir)
    index = read_index(folder.index())
    records = {m["name"]: m for m in index["maps"]}
    out = {}
    for light in dict.fromkeys(spec.input_lights + spec.target_lights):
        if light not in records:
            raise CurationError(
                f"object {spec.id}: light {light!r} is not in {folder.index()} (made for another object list or "
                "light pool: there is a map per object and light); re-run `frng envmaps` with the same config"
            )
        try:
            envmap.read(folder.envmap(light))  # raises naming the file if missing/corrupt
        except envmap.EnvMapError as e:
            raise CurationError(f"object {spec.id}: {e}") from e
        out[light] = records[light]
    return out


def object_scene(
    plan: catalog.Catalog, objaverse: dataset_config.ObjaverseConfig, render: dataset_config.RenderConfig, spec, log
):
    """Inside Blender: a new scene holding object ``spec`` (:class:`frng.plan.catalog.ObjectSpec`) with its mesh and
    material exactly as every curation of it builds them (the shape and material draws seeded by ``spec.seed``),
    a camera and the G-buffer passes. Returns ``(scene, camera, material record, shape record, licence,
    Objaverse provenance or None)``. Used by :func:`curate` and :func:`curate_baselines`, so the baselines' extra
    views show the very object of the dataset."""
    from frng.blender import materials, objects
    from frng.blender import scene as bscene

    _, shape_rng, mat_rng = (np.random.default_rng(s) for s in np.random.SeedSequence(spec.seed).spawn(3))
    scene = bscene.new_scene(render.resolution, render.spp, render.threads, spec.seed)
    bscene.set_sampling(
        scene, render.spp, render.denoise, render.clamp_direct, render.clamp_indirect, render.denoise_prefilter
    )
    bscene.enable_gbuffer_passes(scene)
    cam = bscene.add_camera(scene, render.fov_deg)
    own = spec.material == catalog.OWN
    mat = {"class": catalog.OWN} if own else materials.sample(mat_rng, spec.material, render.fur_strands)
    radius = 1.0 - mat["hair"]["length"] if "hair" in mat else 1.0  # fur stays inside the unit sphere
    pybullet_dir = object_files.pybullet_data_dir() if spec.source == "pybullet" else None
    mesh_path = object_files.objaverse_glb(objaverse, spec.mesh, lambda: plan) if spec.source == "objaverse" else None
    licence, provenance = spec.licence, None
    if mesh_path is not None:
        ann = object_files.objaverse_glb_annotation(objaverse, spec.mesh, mesh_path) or {}
        provenance = {"uid": spec.mesh, "file": str(mesh_path)} | {
            k: ann[k] for k in ("name", "license", "viewerUrl", "uri") if k in ann
        }
        if ann.get("license"):
            licence = f"{ann['license']} (Objaverse 1.0 / Sketchfab: {ann.get('viewerUrl', spec.mesh)})"
    try:
        obj, shape = objects.load(spec, shape_rng, pybullet_dir, radius, keep_materials=own, path=mesh_path)
    except objects.MeshError as e:
        raise CurationError(str(e)) from e
    if own:
        asset = objects.mesh_path(spec, pybullet_dir, mesh_path)
        mat = materials.adopt(obj, [asset if asset.is_dir() else asset.parent])
        for fix in mat["textures_relinked"]:
            log(f"[{spec.id}] texture {fix['from']} does not load; using {fix['to']} (found in the asset's folder)")
        for fix in mat["ior_fixed"]:
            log(
                f"[{spec.id}] material slot {fix['slot']} ({fix['material']}): {fix['change']} (IOR 1 reflects nothing)"
            )
        for bad in mat["unsupported"]:
            log(
                f"[{spec.id}] material slot {bad['slot']} ({bad['material']}): the G-buffer cannot describe "
                f"{', '.join(bad['reasons'])}"
            )
    else:
        materials.apply(obj, mat, spec.seed)
    return scene, cam, mat, shape, licence, provenance


def render_view(scene, cam, raw: Path, view: rig.View, spec, what: str) -> tuple[dict[str, np.ndarray], float]:
    """Inside Blender: render ``view`` of object ``spec`` into ``raw`` and read its passes back; returns
    ``(passes, seconds)``. A render with NaN/Inf pixels or nothing covered is a :class:`CurationError` naming the
    object and ``what`` (``{kind}/{light}/{view}``)."""
    from frng.blender import scene as bscene

    bscene.set_camera_pose(cam, view.c2w)
    dt = bscene.render_to(scene, raw)
    passes = bscene.read_passes(raw)
    rgba = passes["rgba"]
    if not np.isfinite(rgba).all():
        raise CurationError(f"object {spec.id}: {what} has NaN/Inf pixels")
    if rgba[..., 3].max() <= 0.0:
        raise CurationError(f"object {spec.id} ({spec.source}:{spec.mesh}): {what} rendered empty (all alpha 0)")
    return passes, dt


def curate(
    plan: catalog.Catalog,
    objaverse: dataset_config.ObjaverseConfig,
    render: dataset_config.RenderConfig,
    envmaps: dataset_config.EnvmapsConfig,
    oid: str,
    env_dir: Path,
    out_root: Path,
    log=print,
    guard: StopGuard | None = None,
) -> Path:
    """Render object ``oid`` of the dataset plan ``plan`` (:func:`frng.plan.catalog.plan`) into ``out_root/oid``
    (atomically). Returns the final folder. The config's sections it reads: ``objects.objaverse`` (the Objaverse
    cache), ``render`` and ``envmaps`` (their width: the light-sampling map's resolution).

    ``guard``: a :class:`StopGuard` (installed after ``import bpy``) that removes the staging folders on SIGINT /
    SIGTERM; every write into them happens under its lock."""
    import bpy  # noqa: F401  (fail early, clearly, if bpy is missing)

    guard = guard or NoGuard()
    from frng.blender import world

    spec = plan.object(oid)
    lights = check_envmaps(spec, env_dir)
    rig_rng = np.random.default_rng(np.random.SeedSequence(spec.seed).spawn(3)[0])
    inputs, targets = rig.object_views(rig_rng, render)

    with staged_object(out_root, oid, guard, log) as stage:
        staged, scratch = stage.folder, stage.scratch
        t_start = time.perf_counter()
        scene, cam, mat, shape, licence, provenance = object_scene(plan, objaverse, render, spec, log)
        own = spec.material == catalog.OWN
        log(
            f"[{oid}] {spec.source}:{spec.mesh} material={spec.material} split={spec.split} "
            f"{shape['vertices']} verts; {len(inputs)} input views x {len(spec.input_lights)} lights, "
            f"{len(targets)} target views x {len(spec.target_lights)} lights at {render.resolution} px, "
            f"{render.spp} spp"
            + (f" + OpenImageDenoise (prefilter {render.denoise_prefilter})" if render.denoise else "")
        )

        raw = scratch / "raw.exr"
        times: dict[str, dict[str, float]] = {}
        done_gbuffer: set[str] = set()
        n_total = len(inputs) * len(spec.input_lights) + len(targets) * len(spec.target_lights)
        n_done = 0
        for kind, views, light_names in (
            ("inputs", inputs, spec.input_lights),
            ("targets", targets, spec.target_lights),
        ):
            for light in light_names:
                world.set_envmap(
                    scene,
                    Path(EnvmapFolder(env_dir).envmap(light)),
                    sample_map_resolution=max(64, envmaps.width),
                )
                for view in views:
                    passes, dt = render_view(scene, cam, raw, view, spec, f"{kind}/{light}/{view.name}")
                    rgba = passes["rgba"]
                    with guard.lock:
                        io.write_exr(staged.image(kind, light, view.name), rgba, ["R", "G", "B", "A"])
                        if view.name not in done_gbuffer:
                            io.write_exr(staged.gbuffer(view.name), gbuffer_from_passes(passes))
                            done_gbuffer.add(view.name)
                    times.setdefault(light, {})[view.name] = round(dt, 4)
                    n_done += 1
                    log(
                        f"[{oid}] {n_done:4d}/{n_total} {kind}/{light}/{view.name} "
                        f"render {dt:.3f} s  coverage {rgba[..., 3].mean():.3f}"
                    )

        material_class = spec.material
        if own:
            material_class, mat["class_rule"] = own_class(spec, staged, inputs)
            log(f"[{oid}] own material: class {material_class} ({mat['class_rule']})")
        meta = {
            "version": META_VERSION,
            "id": oid,
            "split": spec.split,
            "seed": spec.seed,
            "source": spec.source,
            "mesh": spec.mesh,
            "licence": licence,
            "up_axis": spec.up,
            "shape": shape,
            **({"objaverse": provenance} if provenance else {}),
            "material_class": material_class,
            "material": mat,
            "render": {k: getattr(render, k) for k in RENDER_META_KEYS}
            | {"engine": "CYCLES", "device": "CPU", "blender": __import__("bpy").app.version_string},
            "input_lights": list(spec.input_lights),
            "target_lights": list(spec.target_lights),
            "lights": {
                name: {k: rec[k] for k in ("base", "source", "split", "rotation_deg", "licence", "scale")}
                | {"file": Layout(".").envmap(name)}
                for name, rec in lights.items()
            },
            "views": {"inputs": [v.to_dict() for v in inputs], "targets": [v.to_dict() for v in targets]},
            "gbuffer_channels": list(GBUFFER_CHANNELS),
            "render_seconds": times,
            "total_seconds": round(time.perf_counter() - t_start, 3),
        }
        stage.commit(meta)
    return stage.final
