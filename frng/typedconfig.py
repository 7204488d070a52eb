"""The typed pipeline config: one frozen :class:`Config`, assembled from the section classes the components declare.

Each component declares the dataclass of the config section it reads beside its own code and registers it by its
dotted schema key (:func:`frng.plan.sections.register`); this module imports them all, so it is the one place that knows
every section, and only the stage layer (``frng/stages``; tests, benchmarks) imports it. A stage builds the whole
config once (:func:`typed`) and hands each library the section(s) it reads. Each key is declared once, on its
section's field (:func:`frng.plan.sections.key`): ``config/schema.yaml`` and config/README.md's key tables are
generated from :class:`Config` (:mod:`frng.plan.schema_gen`; tests/test_config_declared.py).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

from frng.baselines.fit_settings import FitSettings
from frng.baselines.plan import BaselinesConfig
from frng.metrics import EvalConfig
from frng.model.composed_config import FRNGSection
from frng.model.saliency import SaliencyConfig
from frng.nn import ModelConfig
from frng.plan.dataset_config import (
    EnvmapsConfig,
    LiberoConfig,
    NoiseFloorConfig,
    ObjaverseConfig,
    ObjectsConfig,
    RenderConfig,
    SkiesConfig,
    StudioConfig,
)
from frng.plan.sections import REQUIRED, key, register, section, section_dict
from frng.render.raster import RasterConfig
from frng.render.shading import ShadingConfig
from frng.training.backbone import BackboneTrainConfig, BackboneTrainingSection
from frng.training.frng_trainer_config import LossConfig, TrainConfig
from frng.training.idm import IDMTrainConfig, IDMTrainingSection


@register("")
@dataclass(frozen=True)
class Config:
    """The validated pipeline config, typed: one frozen section per top-level key (:data:`SECTION_CLASSES`).

    Build it once per stage with :func:`typed`; ``config.train.steps``, ``config.render.resolution``, ..."""

    CONFIG_DOC = (
        "Validated by rules/common.smk (and by every `frng` stage) before any job runs. Unknown keys are errors. "
        "Generated, like the key tables of config/README.md, from the keys the section dataclasses declare "
        "(frng.plan.sections.key)."
    )

    tier: str = key(
        REQUIRED,
        "informational label shown in tables and reports",
        type="string",
        enum=["smoke", "default", "paper", "custom"],
    )
    seed: int = key(
        0,
        "master seed of the data (objects, splits, lights, views: the dataset plan); also the models' seed unless "
        "`train_seed` is set",
        type="integer",
        minimum=0,
    )
    train_seed: int | None = key(
        None,
        "seed of the learned models (backbone, IDM, F-RNG: initialisation and sample order); null = `seed`. A second "
        "seed on the same data: `--config train_seed=1` (in its own results folder)",
        type=["integer", "null"],
        minimum=0,
    )
    results: str = key(
        "results",
        "folder every output goes to; any characters but braces (Snakemake wildcards) and control characters (spaces "
        "and quotes are fine: the rules quote every path). Besides the outputs it holds `config.yaml`, `.digests/` "
        "(each rule's config digest) and `.lock` (see the docs/provenance-and-reproducibility.md)",
        type="string",
        minLength=1,
    )
    device: str = key(
        "auto",
        "torch device for model stages",
        type="string",
        enum=["auto", "cpu", "cuda"],
    )
    benchmarks: tuple = key(
        [],
        "public benchmark scenes imported into the dataset contract, relit by the trained models and scored with "
        "their published protocols (see `benchmarks` below)",
        type="array",
        items={
            "type": "object",
            "additionalProperties": False,
            "required": ["layout", "path"],
            "properties": {
                "layout": {
                    "type": "string",
                    "enum": ["tensoir", "orb", "owl", "nerf-synthetic"],
                    "description": "the published layout (`frng import LAYOUT PATH`)",
                },
                "path": {
                    "type": "string",
                    "description": "tensoir: the scene folder (`train_*/`, `test_*/`; maps in `../light_probes/`); orb: `blender_HDR/{scene}` (maps in `../../ground_truth/`); owl: `dataset/{object}/test`; nerf-synthetic: the scene folder",
                },
                "id": {
                    "type": ["string", "null"],
                    "pattern": "^[a-z0-9_]+-[a-z0-9_-]+$",
                    "default": None,
                    "description": "object id, must contain a hyphen (default `{layout}-{scene}`)",
                },
                "max_targets": {
                    "type": ["integer", "null"],
                    "minimum": 1,
                    "maximum": 10000,
                    "default": None,
                    "description": "keep the first N test views (null: all)",
                },
                "options": {
                    "type": "object",
                    "default": {},
                    "description": "reader options: envmaps, input_light, lights (tensoir), ground_truth (orb), envmap_file (nerf-synthetic), allow_outside (any: true reads files the scene's files name outside its folder; docs/reliability.md)",
                },
            },
        },
    )
    envmaps: EnvmapsConfig = key({}, required=True)
    objects: ObjectsConfig = key(REQUIRED)
    render: RenderConfig = key(REQUIRED)
    baselines: BaselinesConfig = key({})
    backbone: BackboneTrainingSection = key({})
    idm: IDMTrainingSection = key({})
    eval: EvalConfig = key({})
    raster: RasterConfig = key({})
    shading: ShadingConfig = key({})
    model: ModelConfig = key({})
    frng: FRNGSection = key({})
    train: TrainConfig = key({})

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
