"""The ``baselines.fit`` config section: the per-scene baselines' optimisation budget and schedule (torch-free: the
planning code imports it through :mod:`frng.baselines.plan`). Each key is declared on its field below; the
measured costs behind the default tier's values: :mod:`frng.baselines.splat3d`."""

from __future__ import annotations

from dataclasses import dataclass

from frng.plan.sections import FINITE, key, register

INITS = ("hull", "sphere")


@register("baselines.fit")
@dataclass(frozen=True)
class FitSettings:
    """The config's ``baselines.fit`` section (each key declared on its field)."""

    CONFIG_DOC = (
        "the per-scene baselines' optimisation (frng/baselines/perscene.py, splat3d.py, gsir.py; stage baseline-fit); "
        "schedule keys are fractions of the stage's steps (3DGS's 500 / 15k / 100 / 3k of 30k)"
    )

    steps: int = key(
        300,
        "per-scene fit steps, one training view each: `3dgs`'s whole fit and `gsir`'s geometry stage (3DGS / GS-IR: "
        "30000)",
        type="integer",
        minimum=1,
        maximum=10000000,
    )
    pbr_steps: int = key(
        100,
        "`gsir`'s material stage (GS-IR: 5000)",
        type="integer",
        minimum=0,
        maximum=10000000,
    )
    sh_degree: int = key(
        3,
        "largest SH degree of the splats' colour, raised by one every 1/30 of the steps (3DGS)",
        type="integer",
        minimum=0,
        maximum=3,
    )
    init: str = key(
        "hull",
        "starting points: inside the visual hull of the training masks (coloured by their pixels), or uniform in the "
        "unit ball (3DGS starts from SfM points)",
        type="string",
        enum=["hull", "sphere"],
    )
    init_points: int = key(
        2000,
        "starting Gaussians",
        type="integer",
        minimum=16,
        maximum=10000000,
    )
    max_gaussians: int | None = key(
        4000,
        "densification stops at this many Gaussians (a CPU step's cost grows with it); null: no cap",
        type=["integer", "null"],
        minimum=16,
        maximum=10000000,
    )
    lr_scale: float = key(
        4.0,
        "factor on 3DGS's learning rates (1 at 3DGS's 30k steps, the paper tier; a few hundred steps need ~4)",
        type="number",
        exclusiveMinimum=0,
        maximum=100,
        **FINITE,
    )
    pbr_lr: float = key(
        0.02,
        "Adam learning rate of `gsir`'s albedo / roughness / metallic logits",
        type="number",
        exclusiveMinimum=0,
        maximum=10,
        **FINITE,
    )
    views_per_step: int = key(
        1,
        "training views rendered per step (3DGS: 1)",
        type="integer",
        minimum=1,
        maximum=1000,
    )
    densify_from: float = key(
        0.0167,
        "first densification, a fraction of the stage's steps (3DGS: 500 / 30k)",
        type="number",
        minimum=0,
        maximum=1,
    )
    densify_until: float = key(
        0.5,
        "last densification and opacity reset (3DGS: 15k / 30k)",
        type="number",
        minimum=0,
        maximum=1,
    )
    densify_every: float = key(
        0.0333,
        "densification interval (3DGS: 100 / 30k)",
        type="number",
        exclusiveMinimum=0,
        maximum=1,
    )
    reset_every: float = key(
        0.1,
        "opacity reset interval (3DGS: 3000 / 30k)",
        type="number",
        exclusiveMinimum=0,
        maximum=1,
    )
    densify_grad: float = key(
        0.0002,
        "view-space (NDC) positional-gradient threshold of clone / split (3DGS)",
        type="number",
        exclusiveMinimum=0,
    )

    def __post_init__(self):
        if self.init not in INITS:
            raise ValueError(f"baselines.fit.init: {self.init!r} is not one of {', '.join(INITS)}")
        if not 0.0 <= self.densify_from <= self.densify_until <= 1.0:
            raise ValueError("baselines.fit.densify_from / densify_until: need 0 <= from <= until <= 1")

    def every(self, fraction: float, steps: int) -> int:
        """A schedule fraction of a stage of ``steps`` steps as a step count (at least 1)."""
        return max(1, round(float(fraction) * int(steps)))
