"""Relight one held-out object with every F-RNG run and with the backbone (stage :mod:`frng.stages.relight`,
``frng relight --object OBJ``).

What one job does (one test object, all runs, so the paper-scale DAG stays at one job per test object):

1. validates the inputs before anything is written: the object's meta.json, every input view EXR (present,
   readable, RGBA, ``render.resolution`` square), every target light's env map (present, readable, 2:1).
   Any problem raises :class:`RelightError` naming the file; no output folder is touched;
2. per input-view count V (6, and the #views sweep 2, 4, 8, 10 where the object has them), LIVE backbone
   geometry + appearance tokens under the reference light E_0 (the same seeded DDIM pass the cache stage runs, so
   tokens match the training distribution) and live IDM priors -- timed. No run but the labelled oracle
   ``plus-known-light`` reads the input views' light (the paper's task: photos, cameras, masks and the target
   light);
3. per run (:func:`runs`): load ``{results}/models/{variant}/model.pt``, reconstruct once (timed), render the
   reconstruction under every target light at every target view (timed per light);
4. the baseline: the backbone relit under each target light (one full DDIM pass per light, then rendering the
   target views; timed per light), at the same views and resolution;
5. writes, per run, ``{results}/relight/{run}/{obj}/{light}/{view}.exr`` (linear premultiplied RGBA) and
   ``run.json``; the full and F-RNG+ runs (:data:`~frng.plan.variants.ASSET_RUNS`) also keep their relightable
   asset (``asset/``, :mod:`frng.apps.asset`) and their saliency (``saliency.npz``: ``saliency`` (V, H, W), ``patch_idx`` (V, n), ``image`` (V, H, W, 4)); and
   ``{results}/relight/timing/{obj}.json`` with both methods' costs side by side.

Everything is first written to a staging folder ``{results}/relight/.staging-{obj}-*`` and each run folder is
renamed into place only after the whole object succeeded.

Groups (``group``, :func:`frng.plan.variants.run_groups`): the workflow relights an object in one job per group, the
``main`` group (the models' seed runs and the backbone, timed side by side: it writes the timing) and one per
other training seed (its ``{variant}@s{seed}`` runs only, no timing), so that relighting of the first seed's
models overlaps the other seeds' trainings; ``all`` (the CLI's default) does every run in one job.

Runs
----
``full`` (V = 6, K = ``frng.top_k_percent``), the ablations of ``frng.variants`` (``no-fine``, ``no-idm``,
``no-ind``, ``no-neural``), the K sweep ``k1``, ``k4``, ``k8`` (``frng.k_sweep``; their own trained models; the
entry equal to the full model's K is the full run), the #views sweep ``full-v{V}`` (the full model fed V input
views), ``full-oracle``, the other training seeds ``{variant}@s{seed}`` (``train.seeds``), ``plus`` (F-RNG+), ``plus-base``
(F-RNG+'s Lambertian base alone: :func:`shade_base`), ``plus-known-light`` (the oracle told the input light), and
``backbone`` (:func:`frng.plan.variants.runs`).

Timing (``timing/{obj}.json``)
------------------------------
``frng.reconstruction_s``: backbone geometry + appearance tokens (input light) + IDM priors + F-RNG
reconstruction, V = 6; ``frng.relight_ms_per_image``: the target views' G-buffer is rasterized once
(``raster_ms_per_view``, light-independent) and shaded per light (``shade_ms_per_image``); per image = shading +
the rasterization amortised over the job's lights; ``backbone.reconstruction_s``: backbone geometry;
``backbone.relight_ms_per_image``: one full denoising pass + rendering the target views, per image. Same
resolution (the dataset's), same device, same job; F-RNG's ``spp`` is ``shading.spp_infer`` (the backbone has
no light sampling: SH radiance).
"""

from __future__ import annotations

import os
import shutil
import tempfile
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import torch

from frng import io
from frng.device import resolve_device, synchronize
from frng.plan.catalog import Catalog
from frng.plan.layout import Layout, RelightFolder, TrainingFolder
from frng.plan.sections import TypedConfig
from frng.plan.variants import (  # noqa: F401
    ALL_GROUPS,
    ASSET_RUNS,
    BACKBONE,
    PLUS,
    PLUS_METHOD,
    RIG_VIEWS,
    Run,
    RunPlan,
    model_variants,
    runs,
)
from frng.priors.backbone_config import BackboneSection
from frng.priors.idm import IDMSection
from frng.render import envmap
from frng.render.shading import ShadingConfig


class RelightError(ValueError):
    """Bad input to ``frng relight`` (names the file at fault); nothing was written."""


@dataclass(frozen=True)
class RelightJob:
    """What relighting reads of the config, picked out by the stage (:meth:`of`): the results folder, the data
    ``seed`` (the live backbone's DDIM seeds and the light-sample seeds), ``render.resolution``, the default
    ``device``, the ``shading``, ``idm`` and ``backbone`` sections (inference spp; the IDM, :func:`frng.priors.
    build_idm`), the runs (:class:`frng.plan.variants.RunPlan`) and the dataset plan (:func:`frng.plan.catalog.plan`:
    the split an object is planned in)."""

    results: str
    seed: int
    resolution: int
    device: str
    shading: ShadingConfig
    idm: IDMSection
    backbone: BackboneSection
    runs: RunPlan
    plan: Catalog

    @classmethod
    def of(cls, config: TypedConfig) -> RelightJob:
        """The job of the typed config (``frng.typedconfig.Config``)."""
        from frng.plan import catalog

        return cls(
            results=config.results,
            seed=config.seed,
            resolution=int(config.render.resolution),
            device=config.device,
            shading=config.shading,
            idm=config.idm,
            backbone=config.backbone,
            runs=RunPlan.of(config),
            plan=catalog.plan(config),
        )


# -- validation --------------------------------------------------------------------------------------


def validate_inputs(job: RelightJob, oid: str) -> dict:
    """Check everything ``relight`` reads, before anything is written. Returns the object's meta.json.

    Raises :class:`RelightError` naming the file: missing/unreadable meta.json, an object of the training split
    (relighting evaluates held-out objects), a missing, corrupt or non-RGBA input view (no alpha channel: the
    masks are part of the input), an input view that is not ``render.resolution`` square, a missing or non-2:1
    env map."""
    L = Layout(job.results)
    meta_path = Path(L.object_meta(oid))
    try:
        meta = io.read_json(meta_path)
    except (FileNotFoundError, ValueError) as e:
        raise RelightError(f"{meta_path}: cannot read object metadata ({e})") from e
    for key in ("views", "input_lights", "target_lights"):
        if key not in meta:
            raise RelightError(f"{meta_path}: missing key {key!r}")
    check_test_split(job.plan, oid, meta, meta_path)
    res = job.resolution
    light_in = meta["input_lights"][0]
    for cam in meta["views"]["inputs"]:
        path = L.object_image(oid, "inputs", light_in, cam["name"])
        try:
            img = io.read_rgba(path, require_alpha=True)
        except io.ImageError as e:
            raise RelightError(f"input view: {e}") from e
        if img.shape[:2] != (res, res):
            raise RelightError(
                f"{path}: input view is {img.shape[1]}x{img.shape[0]}, expected {res}x{res} (render.resolution)"
            )
        if not np.all(np.isfinite(img)):
            raise RelightError(f"{path}: input view contains NaN or inf")
    for light in dict.fromkeys([light_in] + list(meta["target_lights"])):
        try:
            envmap.read(L.envmap(light))
        except envmap.EnvMapError as e:
            raise RelightError(f"environment map: {e}") from e
    return meta


def check_test_split(plan: Catalog, oid: str, meta: dict, meta_path: Path) -> None:
    """Refuse an object of the training split: its split as curated (``meta.json``'s ``split``) and as the config's
    dataset plan ``plan`` (:class:`frng.plan.catalog.Catalog`) has it must both be ``test``. Raises
    :class:`RelightError` naming the object and the file."""
    from frng.plan import dataset_config

    curated = meta.get("split")
    if isinstance(meta.get("benchmark"), dict):  # imported by `frng import` (frng/benchmarks): no dataset plan
        if curated != "test":
            raise RelightError(f"{meta_path}: imported benchmark object with split {curated!r}, expected 'test'")
        return
    try:
        planned = plan.object(oid).split
    except dataset_config.CatalogError as e:
        raise RelightError(f"{meta_path}: object {oid!r} is not planned by this config ({e})") from e
    for split, source in ((curated, f"{meta_path} (split)"), (planned, "the config's dataset plan")):
        if split is not None and split != "test":
            raise RelightError(
                f"object {oid!r} is in the {split!r} split according to {source}; relighting "
                f"evaluates held-out (test) objects only"
            )


# -- the work ------------------------------------------------------------------------------------------


class Timer:
    """Wall-clock seconds of a block, synchronising CUDA at both ends: ``with Timer(dev) as t: ...; t.s``."""

    def __init__(self, device: torch.device):
        self.device, self.s = device, 0.0

    def __enter__(self):
        synchronize(self.device)
        self.t0 = time.perf_counter()
        return self

    def __exit__(self, *exc):
        synchronize(self.device)
        self.s = time.perf_counter() - self.t0


def backbone_views(seed: int, backbone, oid: str, views, device) -> dict:
    """The backbone's tokens for V input views, live, keyed as a cache entry (:class:`frng.priors.cache.
    BackboneCache.views`): t_geo (V, h, w, D), raw (V, H, W, 9), means/quats/scales/opacities, keep (N,) uint8,
    c2w, intr, light0.t_app (V, h, w, D), light0.sh (N, K, 3), the far-side copies back_*; light 0 = the reference
    light E_0 (:func:`frng.render.envmap.reference_light`; the input views' light is not known), with the DDIM seed
    the cache stage uses (derived from the config's data ``seed``). The backbone is told no input light."""
    from frng.plan import catalog
    from frng.priors.cache import REFERENCE_LIGHT, geometry_entry, reference_env

    rgb, a, c2w, intr = (x.to(device) for x in (views.rgb, views.alpha, views.c2w, views.intr))
    H, W = rgb.shape[1:3]
    recon = backbone.reconstruct(rgb, a, c2w, intr)
    t_geo, _, gauss, keep, _, pixels = recon
    nd = backbone.cfg.den_views
    g = torch.Generator(device=device).manual_seed(catalog.derive_seed(seed, "cache", oid, REFERENCE_LIGHT))
    env0 = reference_env(backbone).to(device)
    sh, t_app = backbone.denoise(t_geo, gauss, keep, env0[None], c2w[:nd], intr[:nd], H, W, generator=g, pixels=pixels)
    return geometry_entry(backbone, recon, a, c2w, intr) | {"light0.t_app": t_app[0].float(), "light0.sh": sh.float()}


def _write_images(folder: Path, light: str, names: list[str], rgba: torch.Tensor) -> None:
    """rgba (Vt, H, W, 4) linear premultiplied -> folder/light/{view}.exr."""
    arr = rgba.detach().float().cpu().numpy()
    for k, name in enumerate(names):
        io.write_exr(RelightFolder(folder).image(light, name), arr[k], channels=["R", "G", "B", "A"])


def relight_object(
    job: RelightJob,
    oid: str,
    models: dict[str, Path],
    backbone_path: Path,
    out_root: Path,
    device: torch.device,
    group: str = ALL_GROUPS,
) -> dict:
    """Do the whole job for one object (see the module docstring): the runs of relighting group ``group``.
    ``models``: variant -> model.pt.

    Writes into ``out_root`` (a staging folder): ``{run}/...`` folders and, for a group holding the full run and the
    backbone, ``timing.json``. Returns the timing (without ``speedup`` and the methods' entries when the group has
    neither)."""
    from frng.model.composed import FRNG
    from frng.plan import catalog
    from frng.priors import build_idm, load_backbone, view_priors
    from frng.priors.dataset import load_object

    idm = build_idm(job.idm, job.backbone, job.results, device)
    meta = io.read_json(Layout(job.results).object_meta(oid))
    the_runs = job.runs.runs(len(meta["views"]["inputs"]), group)
    if isinstance(meta.get("benchmark"), dict):  # imported benchmarks ship no G-buffer: no oracle-prior run
        the_runs = [r for r in the_runs if r.priors != "oracle"]
    need_gbuffer = idm.kind == "oracle" or any(r.priors == "oracle" for r in the_runs)
    obj = load_object(job.results, oid, with_targets=False, with_gbuffer=need_gbuffer)
    light_in = obj.input_lights[0]
    views_all = obj.inputs[light_in]
    cams_t = meta["views"]["targets"]
    t_names = [c["name"] for c in cams_t]
    t_c2w = torch.tensor(np.array([c["c2w"] for c in cams_t]), dtype=torch.float32, device=device)
    t_intr = torch.tensor(np.array([c["intrinsics"] for c in cams_t]), dtype=torch.float32, device=device)
    H, W = views_all.rgb.shape[1:3]
    lights = obj.target_lights or list(meta["target_lights"])
    envs = {l: obj.envs[l].to(device) for l in lights}
    spp = int(job.shading.spp_infer)
    backbone = load_backbone(backbone_path, device)

    # live priors per view count (shared by every run with that V), from exactly the run's V views (view_priors)
    prepared: dict[int, dict] = {}
    with torch.no_grad():
        for V in sorted({r.views for r in the_runs}):
            v = views_all.select(range(V))
            with Timer(device) as t_idm:
                priors = view_priors(idm, obj, light_in, range(V))
            with Timer(device) as t_bb:
                bv = backbone_views(job.seed, backbone, oid, v, device)
            images = torch.cat([v.rgb, v.alpha], -1).to(device)
            prepared[V] = {
                "bv": bv,
                "images": images,
                "priors": priors.to(device),
                "names": v.names,
                "backbone_s": t_bb.s,
                "idm_s": t_idm.s,
            }
            if obj.gbuffer is not None:
                prepared[V]["oracle"] = obj.gbuffer.select(slice(0, V)).to(device)

    timing: dict = {
        "object": oid,
        "device": str(device),
        "resolution": int(H),
        "spp": spp,
        "target_views": len(t_names),
        "lights": len(lights),
        "idm_s": {V: p["idm_s"] for V, p in prepared.items()},
    }
    loaded: dict[str, object] = {}
    for run in the_runs:
        folder = out_root / run.name
        folder.mkdir(parents=True)
        p = prepared[run.views]
        per_light_ms = []
        if run.method == BACKBONE:
            rgb, a = p["images"][..., :3], p["images"][..., 3:4]
            c2w, intr = p["bv"]["c2w"], p["bv"]["intr"]
            nd = backbone.cfg.den_views
            with torch.no_grad():
                with Timer(device) as t_rec:
                    recon = backbone.reconstruct(rgb, a, c2w, intr)
                for light in lights:
                    g = torch.Generator(device=device).manual_seed(catalog.derive_seed(job.seed, "relight", oid, light))
                    with Timer(device) as t_l:
                        rgba = backbone.relight_one(
                            recon, envs[light], c2w[:nd], intr[:nd], t_c2w, t_intr, H, W, generator=g
                        )
                    per_light_ms.append(1000.0 * t_l.s / len(t_names))
                    _write_images(folder, light, t_names, rgba)
            rec_s = t_rec.s
        else:
            if run.variant not in loaded:
                loaded[run.variant] = FRNG.load(models[run.variant], device).set_inference_shading(job.shading)
            model = loaded[run.variant]
            priors = (p["oracle"] if run.priors == "oracle" else p["priors"]) if model.cfg.uses_priors else None
            with torch.no_grad():
                with Timer(device) as t_rec:
                    # the input views' light only for the labelled oracle run (run.light "known"); every other run
                    # estimates it from the photos or does not read it (the paper's task)
                    told = obj.envs[light_in].to(device) if run.light == "known" else None
                    rec = model.reconstruct(p["bv"], 0, priors, p["images"], input_env=told)
                # the G-buffer of the target views does not depend on the light: rasterize once, shade per light
                with Timer(device) as t_ras:
                    raster = model.rasterize(rec, t_c2w, t_intr, H, W)
                shade_ms = []
                for light in lights:
                    g = torch.Generator(device=device).manual_seed(
                        catalog.derive_seed(job.seed, "relight-frng", oid, light)
                    )
                    with Timer(device) as t_l:
                        rgba = (
                            shade_base(model, raster, envs[light])
                            if run.decoder == "base"
                            else model.shade(raster, envs[light], spp, generator=g)
                        )
                    shade_ms.append(1000.0 * t_l.s / len(t_names))
                    _write_images(folder, light, t_names, rgba)
            raster_ms = 1000.0 * t_ras.s / len(t_names)
            # per image: shading under its light + the rasterization amortised over the lights of this job
            per_light_ms = [ms + raster_ms / len(lights) for ms in shade_ms]
            rec_s = t_rec.s + p["backbone_s"] + p["idm_s"]
            if run.name in ASSET_RUNS:
                _save_extras(folder, model, rec, p, oid, run)
        info = asdict(run) | {
            "object": oid,
            "lights": lights,
            "target_views": t_names,
            "input_views": p["names"],
            "resolution": int(H),
            "spp": spp if run.method != BACKBONE else None,
            "reconstruction_s": rec_s,
            "relight_ms_per_image": float(np.mean(per_light_ms)),
            "relight_ms_per_light_image": per_light_ms,
        }
        if run.method != BACKBONE:
            info |= {"raster_ms_per_view": raster_ms, "shade_ms_per_image": float(np.mean(shade_ms))}
        io.write_json(RelightFolder(folder).record(), info)
        if run.name in ("full", PLUS, BACKBONE):
            key = PLUS_METHOD if run.name == PLUS else run.method
            timing[key] = {
                "reconstruction_s": rec_s,
                "relight_ms_per_image": float(np.mean(per_light_ms)),
                "spp": info["spp"],
            }
            if run.method != BACKBONE:
                timing[key] |= {"raster_ms_per_view": raster_ms, "shade_ms_per_image": float(np.mean(shade_ms))}
    if BACKBONE in timing and "F-RNG" in timing:
        timing["speedup"] = timing[BACKBONE]["relight_ms_per_image"] / timing["F-RNG"]["relight_ms_per_image"]
        io.write_json(staged_timing(out_root), timing)
    return timing


def shade_base(model, raster: tuple, env: torch.Tensor) -> torch.Tensor:
    """The run ``plus-base`` (:data:`frng.plan.variants.BASE_RUN`, the quality ladder's Lambertian row): what
    :meth:`frng.model.composed.FRNG.shade` renders with the decoder's residual and attenuation (and the closed-form
    specular base of ``shading.decoder_specular``) dropped, i.e. only its closed-form Lambertian base d E(n)
    (:func:`frng.render.shading.lambert_sh`, the term ``shade`` adds to the Monte-Carlo residual with
    ``shading.diffuse: sh``; checked equal to ``shade`` with the residual and the specular term zeroed). ``raster``: :meth:`FRNG.rasterize`'s output. Returns RGBA
    (Vt, H, W, 4), linear, premultiplied over black. Needs the cosine decoder (``shading.decoder_cosine``)."""
    from frng.render.shading import lambert_sh

    if model.cfg.head != "neural" or not model.decoder.cosine:
        raise RelightError(
            "the Lambertian-base run needs a neural head with the cosine decoder (shading.decoder_cosine)"
        )
    maps, alpha, _, _ = raster
    sh = envmap.sh_project(env.detach().float().cpu()).float()
    rgb = lambert_sh(maps, alpha, sh, model.shading_cfg.alpha_eps)
    return torch.cat([rgb.float(), alpha], -1)


def _save_extras(folder: Path, model, rec, p: dict, oid: str, run: Run) -> None:
    """An :data:`ASSET_RUNS` run's relightable asset (``frng view --object``, ``frng render-asset``) and its
    saliency (the figures read the full run's)."""
    from frng.apps.asset import render_settings, save_asset

    if rec.features is not None:
        meta = {
            "object_id": oid,
            "source_views": p["names"],
            "decoder": model.decoder_meta(),
            "variant": run.variant,
            "k_percent": run.k_percent,
            **render_settings(model.raster_cfg, model.shading_cfg, model.cfg.max_radius_px),
        }
        save_asset(RelightFolder(folder).asset(), rec.gaussians, rec.features, model.asset_weights(), meta)
    np.savez_compressed(
        RelightFolder(folder).saliency(),
        saliency=rec.saliency.detach().float().cpu().numpy(),
        patch_idx=rec.patch_idx.detach().cpu().numpy(),
        image=p["images"].detach().float().cpu().numpy(),
    )


def staged_timing(staging: Path) -> Path:
    """Where :func:`relight_object` writes the timing in its staging folder (:func:`publish` moves it to
    ``{results}/relight/timing/{oid}.json``)."""
    return Path(staging) / "timing.json"


def publish(staging: Path, results: Path, oid: str) -> None:
    """Move each staged run folder to ``{results}/relight/{run}/{oid}`` and the timing, if staged, to
    ``{results}/relight/timing/{oid}.json`` (an existing, e.g. snakemake-created empty, folder is replaced)."""
    L = Layout(results)
    for folder in sorted(p for p in staging.iterdir() if p.is_dir()):
        dest = Path(L.relight_run(folder.name, oid))
        dest.parent.mkdir(parents=True, exist_ok=True)
        if dest.exists():
            shutil.rmtree(dest)
        os.replace(folder, dest)
    if not staged_timing(staging).exists():
        return
    timing = Path(L.relight_timing(oid))
    timing.parent.mkdir(parents=True, exist_ok=True)
    os.replace(staged_timing(staging), timing)


def relight(
    job: RelightJob, oid: str, models_dir: Path | None = None, device: str | None = None, group: str = ALL_GROUPS
) -> dict:
    """Validate, relight the runs of ``group`` (:func:`frng.plan.variants.run_groups`, default every run) into a staging
    folder, publish. Returns the timing dict (see :func:`relight_object`)."""
    results = Path(job.results)
    L = Layout(results)
    validate_inputs(job, oid)
    models_dir = Path(models_dir or L.models_dir())
    try:
        variants = job.runs.model_variants(group)
    except ValueError as e:
        raise RelightError(str(e)) from e
    models = {v: Path(TrainingFolder(models_dir / v).model()) for v in variants}
    missing = [str(p) for p in models.values() if not p.exists()]
    if missing:
        raise RelightError(f"trained F-RNG model(s) missing: {missing}; run the train rules first")
    backbone = Path(L.backbone_model())
    if not backbone.exists():
        raise RelightError(f"{backbone}: backbone model missing")
    dev = resolve_device(device or job.device)
    Path(L.relight_dir()).mkdir(parents=True, exist_ok=True)
    staging = Path(tempfile.mkdtemp(prefix=f".staging-{oid}-{group}-", dir=L.relight_dir()))
    try:
        timing = relight_object(job, oid, models, backbone, staging, dev, group)
        publish(staging, results, oid)
    finally:
        shutil.rmtree(staging, ignore_errors=True)
    return timing
