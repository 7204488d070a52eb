"""Scoring of the baselines beside F-RNG (stage ``frng baseline-eval``): every run's images against the ground truth
with :func:`frng.metrics.evaluate_pair` under the config's ``eval.protocol`` / ``eval.background`` (the protocol of
``frng evaluate``), one row per image, plus one timing row per run and object.

Tasks:

- ``relight``: the run's image of a target view under a target light vs ``{results}/objects/{obj}/targets/{light}/
  {view}.exr``, every target light x target view of the object's meta.json;
- ``nvs`` (novel-view synthesis): the run's image of a target view under the object's INPUT light vs
  ``{results}/baselines/views/{obj}/targets/{input_light}/{view}.exr`` (rule ``curate_baselines``).

Runs (:func:`planned_runs`; :class:`ScoredRun`):

========================= ======== ======== ============ ===============================================
run                       relight  nvs      source       objects
========================= ======== ======== ============ ===============================================
``full``                  yes      --       trained here every test object (``frng relight``)
``full-nvs``              --       yes      trained here objects with baseline views (``frng baseline-frng-nvs``)
``{method}-v{n}``         relights yes      trained here the per-scene baselines' objects (``3dgs``: nvs;
                                                         ``gsir``: both; :mod:`frng.baselines.registry`)
``idm-reshade``           yes      --       trained here objects with baseline views (``baselines.image_based``)
``ext-{name}``            yes      dense*   files        every test object (``baselines.external``)
========================= ======== ======== ============ ===============================================

(*) an external ``dense`` method is scored on novel views where its object folder has the input light's folder.

Outputs: ``baselines_per_image.csv`` (:data:`COLUMNS`, then the protocol's ``scale_*``, ``brightness_*``,
``fg_fraction``) and ``baselines_timing.csv`` (:data:`TIMING_COLUMNS`: ``fit_seconds`` = the reconstruction of one
object -- a per-scene fit, F-RNG's backbone + IDM + reconstruction from ``{results}/relight/timing/{obj}.json`` --,
``relight_seconds_per_image``).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from frng import io
from frng import metrics as M
from frng.baselines.external import ExternalMethod
from frng.baselines.plan import FRNG_NVS_RUN, FRNG_RUN, IMAGE_BASED_RUN, TARGETS_KIND
from frng.plan.layout import Layout, ObjectFolder, RelightFolder

TASKS = ("relight", "nvs")
TRAINED, FILES = "trained here", "files"
COLUMNS = (
    "task",
    "run",
    "method",
    "family",
    "views",
    "source",
    "object",
    "dataset",
    "scene",
    "light",
    "view",
    "psnr",
    "ssim",
    "lpips",
    "protocol",
)
TIMING_COLUMNS = ("run", "method", "family", "views", "source", "object", "fit_seconds", "relight_seconds_per_image")


class ScoringError(ValueError):
    """A run or ground-truth file cannot be scored (names the file)."""


@dataclass(frozen=True)
class ScoredRun:
    """One run to score: its ``run`` name, ``method`` label, ``family`` (``frng`` | ``dense`` | ``image``),
    ``source`` (trained here | files), which ``tasks`` it is scored on, its ``objects``, and, for a method read from
    files, its :class:`ExternalMethod` (else its images are ``{results}/relight/{run}/{obj}``)."""

    run: str
    method: str
    family: str
    source: str
    tasks: tuple[str, ...]
    objects: tuple[str, ...]
    external: ExternalMethod | None = field(default=None, compare=False)
    optional: tuple[str, ...] = ()  # objects scored only where the run has them (imported benchmark scenes)

    def present(self, results: str | Path) -> list[str]:
        """The objects to score: every one of ``objects`` and those of ``optional`` the run has a folder for. An
        external method: only the objects its folder has (an error when it has none of them)."""
        if self.external is not None:
            objs = [o for o in (*self.objects, *self.optional) if self.external.object_dir(o).is_dir()]
            if not objs:
                raise ScoringError(
                    f"{self.external.path}: no object folder of any test object (external method {self.external.name!r},"
                    " layout {path}/{obj}/{light}/{view}.png|exr)"
                )
            return objs
        L = Layout(results)
        return [*self.objects, *(o for o in self.optional if Path(L.relight_record(self.run, o)).exists())]


def planned_runs(
    config,
    test_objects: list[str],
    per_scene_objects: list[str],
    view_objects: list[str],
    with_frng_nvs: bool = True,
    benchmark_objects: list[str] = (),
) -> list[ScoredRun]:
    """The runs a config asks ``frng baseline-eval`` to score (module docstring): ``test_objects`` (the test
    split), ``per_scene_objects`` (:func:`frng.baselines.plan.baseline_objects`), ``view_objects`` (the objects with
    baseline views: those of ``curate_baselines``), ``benchmark_objects`` (imported benchmark scenes: F-RNG's
    ``full`` and the external methods are scored on those they have). ``config``: the validated mapping or typed
    config."""
    from frng.baselines.external import methods
    from frng.baselines.plan import per_scene_methods, per_scene_run, view_counts

    as_map = config if isinstance(config, dict) else config.to_dict()
    sec = as_map.get("baselines", {})
    bench = tuple(benchmark_objects)
    runs = [ScoredRun(FRNG_RUN, "F-RNG", "frng", TRAINED, ("relight",), tuple(test_objects), optional=bench)]
    if with_frng_nvs and view_objects and per_scene_objects:
        runs.append(ScoredRun(FRNG_NVS_RUN, "F-RNG", "frng", TRAINED, ("nvs",), tuple(per_scene_objects)))
    for m in per_scene_methods(as_map):
        for n in view_counts(as_map):
            runs.append(
                ScoredRun(per_scene_run(m.name, n), m.name, "dense", TRAINED, m.tasks, tuple(per_scene_objects))
            )
    if sec.get("image_based", True) and view_objects:
        runs.append(ScoredRun(IMAGE_BASED_RUN, IMAGE_BASED_RUN, "image", TRAINED, ("relight",), tuple(view_objects)))
    for m in methods(as_map):
        tasks = ("relight", "nvs") if m.family == "dense" else ("relight",)
        runs.append(ScoredRun(m.run, m.name, m.family, FILES, tasks, tuple(test_objects), m, optional=bench))
    return runs


def _object_meta(results: Path, oid: str) -> dict:
    path = Layout(results).object_meta(oid)
    try:
        meta = io.read_json(path)
        for key in ("target_lights", "views", "material_class"):
            meta[key]  # noqa: B018 (presence check)
        return meta
    except (FileNotFoundError, ValueError) as e:
        raise ScoringError(f"{path}: cannot read object metadata ({e})") from e
    except KeyError as e:
        raise ScoringError(f"{path}: missing key {e}") from e


def _views_meta(results: Path, oid: str) -> dict:
    path = Layout(results).baseline_views_meta(oid)
    try:
        meta = io.read_json(path)
        meta["light"], meta["views"][TARGETS_KIND]  # noqa: B018
        return meta
    except (FileNotFoundError, ValueError) as e:
        raise ScoringError(f"{path}: cannot read the baseline views' metadata ({e}); run curate_baselines") from e
    except (KeyError, TypeError) as e:
        raise ScoringError(f"{path}: missing key {e}") from e


def _record(results: Path, run: ScoredRun, oid: str) -> dict:
    if run.external is not None:
        return run.external.record(oid)
    path = RelightFolder(Layout(results).relight_run(run.run, oid)).record()
    try:
        return io.read_json(path)
    except (FileNotFoundError, ValueError) as e:
        raise ScoringError(f"{path}: cannot read the run's record ({e})") from e


def pairs(results: Path, run: ScoredRun, oid: str, task: str) -> list[tuple[str, str, Path]]:
    """(light, view, ground-truth path) of one object's images of ``task``."""
    results = Path(results)
    if task == "relight":
        meta = _object_meta(results, oid)
        L = Layout(results)
        names = [v["name"] for v in meta["views"]["targets"]]
        out = [(l, v, Path(L.object_image(oid, "targets", l, v))) for l in meta["target_lights"] for v in names]
        if isinstance(meta.get("benchmark"), dict):  # imported benchmarks: only the pairs with a ground truth
            out = [p for p in out if p[2].exists()]
        return out
    vm = _views_meta(results, oid)
    folder = ObjectFolder(Layout(results).baseline_views_dir(oid))
    light = vm["light"]
    return [(light, v["name"], Path(folder.image(TARGETS_KIND, light, v["name"]))) for v in vm["views"][TARGETS_KIND]]


def read_prediction(results: Path, run: ScoredRun, oid: str, light: str, view: str, gt: np.ndarray) -> np.ndarray:
    """The run's image of (obj, light, view): (H, W, 4) linear premultiplied RGBA at the ground truth's size; errors
    name the file."""
    if run.external is not None:
        return run.external.read(oid, light, view, gt)
    path = Layout(results).relight_image(run.run, oid, light, view)
    pred = io.read_rgba(path, require_alpha=True)
    if pred.shape != gt.shape:
        raise ScoringError(f"{path}: {pred.shape[1]}x{pred.shape[0]}, the ground truth is {gt.shape[1]}x{gt.shape[0]}")
    return pred


def score_run(results: Path, run: ScoredRun, protocol: str, background, device: str = "cpu") -> list[dict]:
    """Per-image rows (:data:`COLUMNS` + the protocol's extra columns) of one run over its objects and tasks."""
    results = Path(results)
    rows = []
    for oid in run.present(results):
        meta = _object_meta(results, oid)
        rec = _record(results, run, oid)
        bench = meta.get("benchmark") if isinstance(meta.get("benchmark"), dict) else {}
        views = rec.get("views", 1 if run.family == "image" else None)  # image-based: the target view's own photo
        for task in run.tasks:
            if task == "nvs" and run.external is not None:  # a dense method's novel views, where it gives them
                has_views = Path(Layout(results).baseline_views_meta(oid)).exists()
                if not has_views or not run.external.has_light(oid, _views_meta(results, oid)["light"]):
                    continue
            for light, view, gt_path in pairs(results, run, oid, task):
                gt = io.read_rgba(gt_path, require_alpha=True)
                pred = read_prediction(results, run, oid, light, view, gt)
                m = M.evaluate_pair(pred, gt, protocol=protocol, background=background, device=device)
                rows.append(
                    {
                        "task": task,
                        "run": run.run,
                        "method": run.method,
                        "family": run.family,
                        "views": None if views is None else int(views),
                        "source": run.source,
                        "object": oid,
                        "dataset": meta["material_class"],
                        "scene": bench.get("scene", ""),
                        "light": light,
                        "view": view,
                    }
                    | m
                )
    return rows


def timing_rows(results: Path, run: ScoredRun) -> list[dict]:
    """One row per object: the reconstruction seconds and seconds per relit image of the run (NaN where the run or
    the method's user did not record them). F-RNG's ``full``: ``{results}/relight/timing/{obj}.json``."""
    results = Path(results)
    out = []
    for oid in run.present(results):
        rec = _record(results, run, oid)
        fit, per_image = rec.get("fit_seconds"), rec.get("relight_seconds_per_image")
        if run.run == FRNG_RUN:
            path = Layout(results).relight_timing(oid)
            try:
                t = io.read_json(path)["F-RNG"]
                fit, per_image = t["reconstruction_s"], t["relight_ms_per_image"] / 1000.0
            except (FileNotFoundError, ValueError, KeyError) as e:
                if oid not in run.optional:
                    raise ScoringError(f"{path}: cannot read F-RNG's timing ({e})") from e
        out.append(
            {
                "run": run.run,
                "method": run.method,
                "family": run.family,
                "views": rec.get("views"),
                "source": run.source,
                "object": oid,
                "fit_seconds": np.nan if fit is None else float(fit),
                "relight_seconds_per_image": np.nan if per_image is None else float(per_image),
            }
        )
    return out


def score(
    results: str | Path, runs: list[ScoredRun], protocol: str, background, out_dir: str | Path
) -> tuple[Path, Path]:
    """Score every run; write ``baselines_per_image.csv`` and ``baselines_timing.csv`` into ``out_dir``. Returns
    their paths."""
    results, out_dir = Path(results), Path(out_dir)
    rows, timing = [], []
    for run in runs:
        rows += score_run(results, run, protocol, tuple(background))
        timing += timing_rows(results, run)
    if not rows:
        raise ScoringError("frng baseline-eval: no images to score")
    df = M.to_frame(rows)
    df = df[list(COLUMNS) + [c for c in df.columns if c not in COLUMNS]]
    tf = M.to_frame(timing).reindex(columns=list(TIMING_COLUMNS))
    return M.write_csv(df, out_dir / "baselines_per_image.csv"), M.write_csv(tf, out_dir / "baselines_timing.csv")


def planned(config) -> list:
    """The runs the config plans (:func:`frng.baselines.scoring.planned_runs` over the dataset plan's test split)."""
    from frng.baselines import plan as P
    from frng.baselines.scoring import planned_runs
    from frng.benchmarks.plan import entries
    from frng.plan import catalog

    cat = catalog.plan(config)
    tests = P.test_objects(cat)
    per_scene = P.baseline_objects(config.to_dict(), tests)
    image = config.baselines.image_based
    # as rules/baselines.smk's BASELINE_VIEW_IDS: every test object when the image-based baseline runs (and there are
    # per-scene objects), else the per-scene objects
    view_objects = [oid for oid, _ in tests] if image and per_scene else per_scene
    bench = [e["id"] for e in entries(config.to_dict())]
    return planned_runs(config, [oid for oid, _ in tests], per_scene, view_objects, benchmark_objects=bench)
