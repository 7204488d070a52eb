"""One per-scene baseline job (stage :mod:`frng.stages.baseline_fit`, ``frng baseline-fit``): read an object's dense
views, fit a per-scene method of :mod:`frng.baselines.registry` (``3dgs``: :mod:`frng.baselines.splat3d`, ``gsir``:
:mod:`frng.baselines.gsir`) on the first ``N`` of them (the nested spread subset
:func:`frng.baselines.plan.dense_subset`) under its input light, and write the RelightFolder ``out``
(``{results}/relight/{method}-v{N}/{obj}``):

- ``{input_light}/{view}.exr``: the object's target views under the input light (novel-view synthesis), every method
  (a relighting one, gsir: under its learned light);
- ``{light}/{view}.exr`` for every target light (methods that relight only: ``3dgs`` cannot);
- ``run.json`` (run, method, views, source, fit_seconds, relight_seconds_per_image, threads, device, steps,
  train_psnr, final_loss, ...) and ``loss.csv`` (step, loss, psnr).

Reads ``{results}/baselines/views/{obj}/`` (meta.json, ``dense/{light}/{view}.exr``), ``{results}/objects/{obj}/
meta.json`` (``target_lights``) and ``{results}/envmaps/{light}.exr`` of the target lights alone (a method that
relights: the task gives them). No method reads the input light's map: gsir learns its light, and its images under
the input light are rendered under that learned light (a target light named as the input light is too). Config keys:
``results``, ``seed``, ``device``, ``raster.*``, the method's settings section (``baselines.fit.*``).

Everything is written into a temporary sibling of ``out`` and renamed onto it at the end: a failed job leaves
nothing that looks valid (and an earlier run's folder as it was). Bad input is one line naming the file.
"""

from __future__ import annotations

import shutil
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from frng import io
from frng.baselines import registry
from frng.baselines.fit_settings import FitSettings
from frng.baselines.plan import DENSE_KIND, dense_subset, per_scene_run
from frng.plan.layout import Layout, ObjectFolder, RelightFolder, TrainingFolder
from frng.plan.sections import TypedConfig

if TYPE_CHECKING:
    from frng.render.raster import RasterConfig


@dataclass(frozen=True)
class FitJob:
    """What a fit reads of the config, picked out by the stage (:meth:`of`): the results folder, the data ``seed``
    (each fit's seed derives from it, the object, the method and the view count), the device, the ``raster``
    section and ``baselines.fit``."""

    results: str
    seed: int
    device: str
    raster: RasterConfig
    fit: FitSettings
    config: TypedConfig | None = field(default=None, compare=False)  # another settings section a method reads

    @classmethod
    def of(cls, config: TypedConfig) -> FitJob:
        return cls(
            str(config.results), int(config.seed), str(config.device), config.raster, config.baselines.fit, config
        )

    def settings(self, method: registry.PerSceneMethod):
        """The settings section ``method`` reads: ``baselines.fit`` (:attr:`fit`) or another of the config."""
        if method.settings == "baselines.fit":
            return self.fit
        if self.config is None:
            raise ValueError(f"per-scene baseline {method.name!r}: no config to read {method.settings!r} from")
        out = self.config
        for key in method.settings.split("."):
            out = getattr(out, key)
        return out


class BaselineFitError(ValueError):
    """Bad input to ``frng baseline-fit`` (names the file at fault); nothing was written."""


def _views_from(dicts: list, where: str):
    from frng.data.rig import View

    try:
        return [View.from_record(d) for d in dicts]
    except (KeyError, TypeError, ValueError) as e:
        raise BaselineFitError(f"{where}: bad view entry ({e})") from e


def read_inputs(results: str, oid: str, views: int) -> dict:
    """Everything the job reads, checked before anything is fitted: the dense views (train subset), the target
    views, the input light's name and the target lights' names (``envmap``: a light's map path; never read here).
    Raises :class:`BaselineFitError` naming the file."""
    L = Layout(results)
    meta_path = L.baseline_views_meta(oid)
    try:
        meta = io.read_json(meta_path)
    except (OSError, ValueError) as e:
        raise BaselineFitError(f"{meta_path}: cannot read the baselines' views ({e})") from e
    for key in ("light", "views"):
        if key not in meta:
            raise BaselineFitError(f"{meta_path}: missing key {key!r}")
    dense = _views_from(meta["views"].get("dense") or [], meta_path)
    targets = _views_from(meta["views"].get("targets") or [], meta_path)
    if not dense:
        raise BaselineFitError(f"{meta_path}: no dense views (is the object a per-scene baseline object?)")
    if not 1 <= views <= len(dense):
        raise BaselineFitError(f"{meta_path}: {views} views asked, the object has {len(dense)} dense views")
    obj_meta_path = L.object_meta(oid)
    try:
        obj_meta = io.read_json(obj_meta_path)
    except (OSError, ValueError) as e:
        raise BaselineFitError(f"{obj_meta_path}: cannot read object metadata ({e})") from e
    if "target_lights" not in obj_meta:
        raise BaselineFitError(f"{obj_meta_path}: missing key 'target_lights'")
    if not targets:
        targets = _views_from(obj_meta.get("views", {}).get("targets") or [], obj_meta_path)
    light = str(meta["light"])
    train = dense_subset(dense, views)
    folder = ObjectFolder(L.baseline_views_dir(oid))
    images = []
    for v in train:
        path = folder.image(DENSE_KIND, light, v.name)
        try:
            rgba = io.read_rgba(path, require_alpha=True)
        except (OSError, ValueError) as e:
            raise BaselineFitError(f"dense view: {e}") from e
        if rgba.shape[:2] != (v.height, v.width):
            raise BaselineFitError(f"{path}: {rgba.shape[1]}x{rgba.shape[0]} px, meta.json says {v.width}x{v.height}")
        if not np.isfinite(rgba).all():
            raise BaselineFitError(f"{path}: NaN or inf")
        images.append(rgba)
    return {
        "light": light,
        "train": train,
        "images": np.stack(images),
        "targets": targets,
        "target_lights": [str(x) for x in obj_meta["target_lights"]],
        "envmap": L.envmap,
    }


def read_env(path: str):
    import torch

    from frng.render import envmap

    try:
        return torch.from_numpy(np.ascontiguousarray(envmap.read(path)[..., :3])).float()
    except (OSError, ValueError) as e:
        raise BaselineFitError(f"environment map: {e}") from e


def fit_object(job: FitJob, oid: str, method: str, views: int, out: Path, device_name: str | None = None) -> dict:
    """The whole job (module docstring); returns the run record."""
    import torch

    from frng.baselines import splat3d
    from frng.baselines.perscene import TrainViews
    from frng.device import deterministic_kernels, resolve_device, training_threads
    from frng.plan import catalog

    spec = registry.method(method)
    run = per_scene_run(method, views)
    inputs = read_inputs(job.results, oid, views)
    envs = {}  # the target maps, given to relight; never the input light's (a relighting method learns it)
    if spec.relights:
        for light in dict.fromkeys(inputs["target_lights"]):
            if light != inputs["light"]:
                envs[light] = read_env(inputs["envmap"](light))
    threads = training_threads()
    device = resolve_device(device_name or job.device)
    deterministic_kernels(device)
    settings, raster = job.settings(spec), job.raster
    seed = catalog.derive_seed(job.seed, "baseline-fit", oid, method, str(views))

    train = inputs["train"]
    imgs = torch.from_numpy(inputs["images"]).to(device)
    tv = TrainViews(
        [v.name for v in train],
        torch.tensor(np.array([v.c2w for v in train]), dtype=torch.float32, device=device),
        torch.tensor(np.array([v.intrinsics for v in train]), dtype=torch.float32, device=device),
        imgs[..., :3].contiguous(),
        imgs[..., 3:4].contiguous(),
    )
    targets = inputs["targets"]
    t_c2w = torch.tensor(np.array([v.c2w for v in targets]), dtype=torch.float32, device=device)
    t_intr = torch.tensor(np.array([v.intrinsics for v in targets]), dtype=torch.float32, device=device)
    t_names = [v.name for v in targets]
    H, W = tv.size
    if any((v.height, v.width) != (H, W) for v in targets):
        raise BaselineFitError(f"{Layout(job.results).baseline_views_meta(oid)}: target views' size is not {W}x{H}")

    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    staging = io.temp_dir(f".staging-{out.name}-", out.parent)
    try:
        t0 = time.perf_counter()
        model = spec.fit_function()(tv, settings, raster, seed, label=f"{method} {oid} v{views}")
        fit_s = time.perf_counter() - t0
        train_psnr = splat3d.train_psnr(lambda c, i, h, w: model.render(c, i, h, w, {})[0], tv)
        t1 = time.perf_counter()
        lit, relit = model.render(t_c2w, t_intr, H, W, {light: env.to(device) for light, env in envs.items()})
        images = {inputs["light"]: lit} | relit
        per_image = (time.perf_counter() - t1) / max(1, len(t_names) * len(images))
        folder = RelightFolder(staging)
        for light, rgba in images.items():
            arr = rgba.detach().float().cpu().numpy()
            for k, name in enumerate(t_names):
                io.write_exr(folder.image(light, name), arr[k], channels=["R", "G", "B", "A"])
        curve = model.curve
        Path(TrainingFolder(staging).curve("csv")).write_text(curve.csv())
        record = {
            "run": run,
            "method": method,
            "object": oid,
            "views": int(views),
            "source": "trained here",
            "fit_seconds": fit_s,
            "relight_seconds_per_image": per_image,
            "threads": int(threads),
            "device": str(device),
            "steps": len(curve.rows),
            "train_psnr": train_psnr,
            "final_loss": curve.mean_loss(first=False, fraction=0.05),
            "first_loss": curve.mean_loss(first=True, fraction=0.05),
            "gaussians": int(model.gaussians),
            "seed": seed,
            "resolution": int(H),
            "input_light": inputs["light"],
            "lights": [x for x in images if x != inputs["light"]],
            "target_views": t_names,
            "train_views": [v.name for v in train],
            "init": getattr(settings, "init", None),
            **model.extra,
        }
        io.write_json(folder.record(), record)
        if out.exists():
            shutil.rmtree(out)
        staging.rename(out)
    except BaseException:
        shutil.rmtree(staging, ignore_errors=True)
        raise
    return record
