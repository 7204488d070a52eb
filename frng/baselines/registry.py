"""The per-scene baselines' registry (torch-free: planning and the rule files read it): one
:class:`PerSceneMethod` per method, read by the plan (:func:`frng.baselines.plan.per_scene_runs`), the fit job
(:func:`frng.baselines.fit_job.fit_object`), the scoring (:func:`frng.baselines.scoring.planned_runs`: its tasks),
the tables (:func:`frng.report.baseline_tables.label`), the stage's ``--method`` choices and ``rules/baselines.smk``.

A method's ``fit`` is ``fit(views, settings, raster, seed, label) -> Fitted`` (:class:`Fitted`), named as
``"module:function"`` (imported when a job fits, so planning stays free of torch) or given as the function. Adding a
per-scene baseline is one module: its fit, and a :func:`register` call (for a plugin: imported before the stages run,
as :mod:`frng.priors.registry`'s backbones and IDMs); ``baselines.methods`` then names it.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any, Protocol

TASKS_RELIGHTS = ("relight", "nvs")
TASKS_NVS = ("nvs",)


class Fitted(Protocol):
    """A fitted per-scene model as the fit job uses it."""

    curve: Any  # frng.baselines.perscene.Curve: the fit's loss curve (loss.csv)
    gaussians: int  # primitives at the end of the fit
    extra: dict  # method-specific entries of run.json

    def render(self, c2w, intr, height: int, width: int, envs: Mapping) -> tuple[Any, dict]:
        """RGBA (V, H, W, 4) linear premultiplied at cameras c2w (V, 4, 4), intr (V, 4) under the input light (as
        the model learned it), and {light: RGBA} under each of ``envs`` ({light: map (He, We, 3)}, empty for a
        method that does not relight)."""


@dataclass(frozen=True)
class PerSceneMethod:
    """One per-scene baseline: its ``name`` (in ``baselines.methods`` and run names ``{name}-v{n}``), its ``label``
    in the tables, what it ``fits`` (one line, for the docs), whether it ``relights`` (then it is scored on
    relighting too and its fit is given the target lights' maps), the dotted config ``settings`` section its fit
    reads, and its ``fit`` (module docstring)."""

    name: str
    label: str
    fits: str
    relights: bool
    fit: str | Callable[..., Fitted]
    settings: str = "baselines.fit"

    @property
    def tasks(self) -> tuple[str, ...]:
        """The tasks its runs are scored on (:mod:`frng.baselines.scoring`)."""
        return TASKS_RELIGHTS if self.relights else TASKS_NVS

    def fit_function(self) -> Callable[..., Fitted]:
        if callable(self.fit):
            return self.fit
        module, _, attr = self.fit.partition(":")
        return getattr(importlib.import_module(module), attr)


PER_SCENE: dict[str, PerSceneMethod] = {}


def register(method: PerSceneMethod) -> PerSceneMethod:
    PER_SCENE[method.name] = method
    return method


def names() -> tuple[str, ...]:
    return tuple(PER_SCENE)


def method(name: str) -> PerSceneMethod:
    """The spec of ``name``; an unknown name is a one-line ValueError naming the config key and the known methods."""
    if name not in PER_SCENE:
        raise ValueError(
            f"config key 'baselines.methods': unknown per-scene baseline {name!r} (known: {', '.join(PER_SCENE)})"
        )
    return PER_SCENE[name]


register(
    PerSceneMethod(
        name="3dgs",
        label="3DGS (per-scene)",
        fits="plain 3D Gaussian splatting with view-dependent colour (novel views only)",
        relights=False,
        fit="frng.baselines.splat3d:fit_baseline",
    )
)
register(
    PerSceneMethod(
        name="gsir",
        label="GS-IR-style (per-scene)",
        fits="Gaussians with normals and PBR materials under a learned light (relightable)",
        relights=True,
        fit="frng.baselines.gsir:fit_baseline",
    )
)
