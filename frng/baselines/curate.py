"""The baselines' extra views (stage ``frng curate-baselines``, rule ``curate_baselines``): ONE Blender process per
test object renders, under the object's FIRST input light,

- its target views (the same cameras as ``objects/{obj}/meta.json``): the ground truth of novel-view synthesis and
  the photo an image-based relighting method is given (Table 3's methods relight each target view's own image);
- for the per-scene baselines' objects (:func:`frng.baselines.plan.baseline_objects`), ``render.dense_views`` views
  on a sphere (:func:`frng.baselines.plan.dense_views`): the dense capture GS-IR / R3DG / 3DGS are fitted on.

The object is built exactly as its curation built it (:func:`frng.data.curate.object_scene`: same mesh, shape and
material draws), with the same Cycles settings (``render``). Writes ``{results}/baselines/views/{obj}/``
(:class:`frng.plan.layout.ObjectFolder`): ``meta.json`` (``light``, ``views: {dense, targets}``, render settings and
times), ``dense/{light}/{view}.exr`` and ``targets/{light}/{view}.exr`` (RGBA float32 linear, premultiplied, alpha
= coverage, as curation writes), staged in ``.tmp-{obj}-*`` and renamed at the end like :func:`frng.data.curate.curate`.
"""

from __future__ import annotations

import time
from pathlib import Path

from frng import io
from frng.baselines.plan import DENSE_KIND, TARGETS_KIND, dense_views
from frng.data.curate import CurationError, check_envmaps, object_scene, render_view, staged_object
from frng.data.rig import View
from frng.data.stopguard import NoGuard, StopGuard
from frng.plan import catalog, dataset_config
from frng.plan.layout import EnvmapFolder

META_VERSION = 1


def curate_baselines(
    plan: catalog.Catalog,
    objaverse: dataset_config.ObjaverseConfig,
    render: dataset_config.RenderConfig,
    envmaps: dataset_config.EnvmapsConfig,
    oid: str,
    object_meta: Path,
    env_dir: Path,
    out_root: Path,
    dense: bool,
    log=print,
    guard: StopGuard | None = None,
) -> Path:
    """Render test object ``oid``'s target views (cameras from its curated ``object_meta``) and, if ``dense``,
    ``render.dense_views`` dense views, all under its first input light, into ``out_root/oid`` (atomically).
    Returns the final folder."""
    import bpy  # noqa: F401  (fail early, clearly, if bpy is missing)

    from frng.blender import world

    guard = guard or NoGuard()
    spec = plan.object(oid)
    if spec.split != "test":
        raise CurationError(f"object {oid}: the baselines run on test objects; its split is {spec.split!r}")
    check_envmaps(spec, env_dir)
    light = spec.input_lights[0]
    try:
        curated = io.read_json(object_meta)
        targets = [View.from_record(d) for d in curated["views"]["targets"]]
    except (OSError, ValueError, KeyError, TypeError) as e:
        raise CurationError(f"{object_meta}: not a curated object's meta.json ({type(e).__name__}: {e})") from e
    if curated.get("id") != oid:
        raise CurationError(f"{object_meta}: its id is {curated.get('id')!r}, not {oid!r}")
    denses = dense_views(render.dense_views, render.camera_distance, render.fov_deg, render.resolution) if dense else []

    with staged_object(out_root, oid, guard, log) as stage:
        staged, scratch = stage.folder, stage.scratch
        t_start = time.perf_counter()
        scene, cam, _, shape, _, _ = object_scene(plan, objaverse, render, spec, log)
        world.set_envmap(scene, Path(EnvmapFolder(env_dir).envmap(light)), sample_map_resolution=max(64, envmaps.width))
        log(
            f"[{oid}] {shape['vertices']} verts; {len(targets)} target views + {len(denses)} dense views under "
            f"{light} at {render.resolution} px, {render.spp} spp"
        )
        raw = scratch / "raw.exr"
        times: dict[str, dict[str, float]] = {TARGETS_KIND: {}, DENSE_KIND: {}}
        jobs = [(TARGETS_KIND, v) for v in targets] + [(DENSE_KIND, v) for v in denses]
        for i, (kind, view) in enumerate(jobs):
            passes, dt = render_view(scene, cam, raw, view, spec, f"{kind}/{light}/{view.name}")
            with guard.lock:
                io.write_exr(staged.image(kind, light, view.name), passes["rgba"], ["R", "G", "B", "A"])
            times[kind][view.name] = round(dt, 4)
            log(f"[{oid}] {i + 1:4d}/{len(jobs)} {kind}/{light}/{view.name} render {dt:.3f} s")
        meta = {
            "version": META_VERSION,
            "id": oid,
            "light": light,
            "views": {DENSE_KIND: [v.to_dict() for v in denses], TARGETS_KIND: [v.to_dict() for v in targets]},
            "render": {k: getattr(render, k) for k in ("resolution", "spp", "camera_distance", "fov_deg", "threads")},
            "render_seconds": times,
            "total_seconds": round(time.perf_counter() - t_start, 3),
        }
        stage.commit(meta)
    return stage.final
