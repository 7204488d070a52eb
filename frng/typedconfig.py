"""The typed pipeline config: one frozen :class:`Config`, assembled from the section classes the components declare.

Each component declares the dataclass of the config section it reads beside its own code and registers it by its
dotted schema key (:func:`frng.plan.sections.register`); this module imports them all, so it is the one place that knows
every section, and only the stage layer (``frng/stages``; tests, benchmarks) imports it. A stage builds the whole
config once (:func:`typed`) and hands each library the section(s) it reads. ``config/schema.yaml`` is the one place
defaults are written (:func:`frng.plan.sections.section`; tests/test_config_typed.py).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

from frng.baselines.fit_settings import FitSettings
from frng.baselines.plan import BaselinesConfig
from frng.metrics import EvalConfig
from frng.model.composed import FRNGSection
from frng.model.saliency import SaliencyConfig
from frng.nn import ModelConfig
from frng.plan.catalog import (
    EnvmapsConfig,
    LiberoConfig,
    NoiseFloorConfig,
    ObjaverseConfig,
    ObjectsConfig,
    RenderConfig,
    SkiesConfig,
    StudioConfig,
)
from frng.plan.sections import register, section, section_dict
from frng.render.raster import RasterConfig
from frng.render.shading import ShadingConfig
from frng.training.backbone import BackboneTrainConfig, BackboneTrainingSection
from frng.training.frng_trainer import LossConfig, TrainConfig
from frng.training.idm import IDMTrainConfig, IDMTrainingSection


@register("")
@dataclass(frozen=True)
class Config:
    """The validated pipeline config, typed: one frozen section per top-level key (:data:`SECTION_CLASSES`).

    Build it once per stage with :func:`typed`; ``config.train.steps``, ``config.render.resolution``, ..."""

    tier: str
    seed: int
    train_seed: int | None
    results: str
    device: str
    envmaps: EnvmapsConfig
    objects: ObjectsConfig
    render: RenderConfig
    backbone: BackboneTrainingSection
    idm: IDMTrainingSection
    eval: EvalConfig
    raster: RasterConfig
    shading: ShadingConfig
    model: ModelConfig
    frng: FRNGSection
    train: TrainConfig
    benchmarks: tuple  # imported benchmark folders (frng/benchmarks; rules/benchmarks.smk)
    baselines: BaselinesConfig  # Tables 2-3 and the views table (frng/baselines)

    @property
    def model_seed(self) -> int:
        """The learned models' seed: ``train_seed``, or the data's ``seed`` when it is null."""
        return int(self.seed if self.train_seed is None else self.train_seed)

    def to_dict(self) -> dict:
        """The config mapping again (equal to the validated dict it was built from)."""
        return section_dict(self, "")


SECTION_CLASSES: tuple[type, ...] = (
    Config,
    BaselinesConfig,
    FitSettings,
    EnvmapsConfig,
    SkiesConfig,
    StudioConfig,
    ObjectsConfig,
    LiberoConfig,
    ObjaverseConfig,
    RenderConfig,
    NoiseFloorConfig,
    BackboneTrainingSection,
    BackboneTrainConfig,
    IDMTrainingSection,
    IDMTrainConfig,
    EvalConfig,
    RasterConfig,
    ShadingConfig,
    ModelConfig,
    FRNGSection,
    SaliencyConfig,
    TrainConfig,
    LossConfig,
)
"""The class of every config section (each registered under its dotted key, :data:`frng.plan.sections.SECTIONS`)."""


def typed(config: Config | Mapping) -> Config:
    """The :class:`Config` of a validated config mapping (:func:`frng.plan.config.load`, :func:`frng.plan.config.validate`);
    a Config is returned as it is."""
    if isinstance(config, Config):
        return config
    return section(Config, config, "")
