"""The ``baselines.fit`` config section: the per-scene baselines' optimisation budget and schedule (torch-free: the
planning code imports it through :mod:`frng.baselines.plan`). Defaults and descriptions: config/schema.yaml; the
measured costs behind the default tier's values: :mod:`frng.baselines.splat3d`."""

from __future__ import annotations

from dataclasses import dataclass

from frng.plan.sections import register

INITS = ("hull", "sphere")


@register("baselines.fit")
@dataclass(frozen=True)
class FitSettings:
    """The config's ``baselines.fit`` section (defaults and descriptions: config/schema.yaml)."""

    steps: int  # 3dgs's steps; gsir's geometry stage
    pbr_steps: int  # gsir's material stage
    sh_degree: int
    init: str
    init_points: int
    max_gaussians: int | None
    lr_scale: float
    pbr_lr: float
    views_per_step: int
    densify_from: float
    densify_until: float
    densify_every: float
    reset_every: float
    densify_grad: float

    def __post_init__(self):
        if self.init not in INITS:
            raise ValueError(f"baselines.fit.init: {self.init!r} is not one of {', '.join(INITS)}")
        if not 0.0 <= self.densify_from <= self.densify_until <= 1.0:
            raise ValueError("baselines.fit.densify_from / densify_until: need 0 <= from <= until <= 1")

    def every(self, fraction: float, steps: int) -> int:
        """A schedule fraction of a stage of ``steps`` steps as a step count (at least 1)."""
        return max(1, round(float(fraction) * int(steps)))
