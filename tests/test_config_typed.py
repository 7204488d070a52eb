"""The typed config (frng/typedconfig.py ``Config``, ``typed``; frng/plan/sections.py ``section``): one frozen dataclass per
schema section, strict (unknown keys are errors), each key declared once on its field (frng.plan.sections.key: the
generated config/schema.yaml holds the same defaults, tests/test_config_declared.py): every object section of the schema
has a registered class whose fields are its keys, and a missing key takes its declared default."""

import dataclasses
import subprocess
import sys
from pathlib import Path

import pytest

from frng.plan import config as fc
from frng.plan import digests
from frng.plan.sections import (
    SECTIONS,
    ConfigError,
    as_dict,
    config_section,
    register,
    schema_defaults,
    schema_keys,
    section,
    section_keys,
)
from frng.typedconfig import SECTION_CLASSES, Config, typed

ROOT = Path(__file__).resolve().parents[1]
SHIPPED = ("config/config.yaml", "config/smoke.yaml", "config/paper.yaml")

INTERNAL = {  # fields a section class holds that are no config keys (documented at the class); each has a default
    "frng.saliency": {"margin", "top_k"},  # top_k is set from frng.top_k_percent by FRNGConfig.saliency_config
    "idm.train": {"weight_decay", "grad_clip"},  # the IDM trainer's fixed values (no config keys)
}


def _has_default(f: dataclasses.Field) -> bool:
    return f.default is not dataclasses.MISSING or f.default_factory is not dataclasses.MISSING


def _records():
    """Architecture records of model files built with ``section``: (class, schema section or None, fields that are
    no keys of that section)."""
    from frng.model.composed_config import FRNGConfig
    from frng.priors.backbone_config import BackboneConfig
    from frng.priors.idm import IDMConfig

    return [
        (BackboneConfig, "backbone", {"patch"}),
        (IDMConfig, "idm", {"patch", "near", "far"}),
        (FRNGConfig, None, None),
    ]


def test_every_schema_section_has_its_class():
    """frng.typedconfig assembles a class for every object section of the schema, and registers no other."""
    assert set(SECTIONS) == set(section_keys()), (sorted(set(section_keys()) - set(SECTIONS)), sorted(set(SECTIONS)))
    assert {SECTIONS[k] for k in SECTIONS} == set(SECTION_CLASSES)


@pytest.mark.parametrize("where", section_keys())
def test_section_fields_are_the_schema_keys(where):
    cls = SECTIONS[where]
    fields = {f.name for f in dataclasses.fields(cls)}
    keys = set(schema_keys(where))
    assert fields - INTERNAL.get(where, set()) == keys, f"{cls.__name__} vs schema section {where or '<root>'}"
    assert dataclasses.is_dataclass(cls) and cls.__dataclass_params__.frozen


@pytest.mark.parametrize("where", section_keys())
def test_no_python_default_for_a_schema_key(where):
    """The schema's defaults are the only defaults: a field that is a schema key has none of its own; internal
    fields (no schema key) have one."""
    keys = set(schema_keys(where))
    for f in dataclasses.fields(SECTIONS[where]):
        if f.name in keys:
            assert not _has_default(f), f"{where}.{f.name}: default written twice (schema and Python)"
        else:
            assert _has_default(f), f"{where}.{f.name}: an internal field needs a default"


def test_model_records_have_no_defaults_and_their_keys():
    for cls, where, extra in _records():
        fields = dataclasses.fields(cls)
        assert not any(_has_default(f) for f in fields), cls.__name__
        if where is not None:
            assert {f.name for f in fields} - extra <= set(schema_keys(where)), cls.__name__


@pytest.mark.parametrize("where", section_keys())
def test_unknown_key_is_an_error_naming_it(where):
    dotted = f"{where}.stepz" if where else "stepz"
    with pytest.raises(ConfigError, match=rf"^{dotted.replace('.', '[.]')}: unknown key; known: "):
        section(SECTIONS[where], {"stepz": 1}, where)


def test_unknown_nested_key_and_model_records():
    d = fc.load(ROOT / "config/smoke.yaml")
    bad = fc.merge(d, {"train": {"loss": {"lambda_x": 1.0}}})
    with pytest.raises(ConfigError, match=r"^train[.]loss[.]lambda_x: unknown key"):
        typed(bad)
    from frng.model.composed_config import FRNGConfig
    from frng.priors.backbone_config import BackboneConfig
    from frng.training.frng_trainer import ModelSections, variant_config

    cfg, _ = variant_config(ModelSections.of(typed(d)), "full")
    assert FRNGConfig.from_dict(cfg.to_dict()) == cfg  # a model file's config loads back
    with pytest.raises(ConfigError, match=r"^FRNGConfig[.]bogus: unknown key"):
        FRNGConfig.from_dict({**cfg.to_dict(), "bogus": 1})
    with pytest.raises(ConfigError, match=r"^FRNGConfig[.]head: missing key"):
        FRNGConfig.from_dict({k: v for k, v in cfg.to_dict().items() if k != "head"})
    # a model saved before a key existed loads with what it was trained with, a current one with its own value;
    # the additions (fine_in_hull, coverage_head, ...) are on in F-RNG+ only (full is the paper's form)
    assert not cfg.fine_in_hull and cfg.coverage_head == 0
    cfg, _ = variant_config(ModelSections.of(typed(d)), "plus")
    assert FRNGConfig.from_dict(cfg.to_dict()) == cfg
    assert cfg.fine_in_hull  # the default
    old_record = {k: v for k, v in cfg.to_dict().items() if k != "fine_in_hull"}
    assert FRNGConfig.from_saved(old_record).fine_in_hull is False
    assert cfg.opacity_head  # the default
    older = {k: v for k, v in cfg.to_dict().items() if k != "opacity_head"}
    assert FRNGConfig.from_saved(older).opacity_head is False
    assert cfg.geometry_inputs and cfg.depth_head > 0  # the defaults
    assert cfg.coverage_head == 16  # the default: on
    assert cfg.specular_start is True  # the default: on
    added = ("geometry_inputs", "depth_head", "coverage_head", "specular_start")
    oldest = {k: v for k, v in cfg.to_dict().items() if k not in added}
    saved = FRNGConfig.from_saved(oldest)
    assert [getattr(saved, k) for k in added] == [False, 0.0, 0, False]
    assert FRNGConfig.from_saved(cfg.to_dict()) == cfg
    with pytest.raises(ConfigError, match=r"^backbone[.]kind: unknown key"):
        BackboneConfig.from_dict({"patch": 8, "kind": "relitlrm"})  # an architecture record, not the section


def test_missing_keys_take_the_schema_defaults():
    from frng.render.shading import ShadingConfig

    t = config_section({"train": {"steps": 7}}, "train")
    assert t.steps == 7 and t.lr == schema_defaults("train")["lr"]
    assert t.loss.lambda_c == schema_defaults("train.loss")["lambda_c"]
    assert ShadingConfig.from_dict({}).spp_infer == schema_defaults("shading")["spp_infer"]


@pytest.mark.parametrize("path", SHIPPED)
def test_shipped_configs_round_trip(path):
    d = fc.load(ROOT / path)
    c = typed(d)
    assert isinstance(c, Config) and typed(c) is c
    assert c.to_dict() == d
    assert c.train.steps == d["train"]["steps"] and c.render.resolution == d["render"]["resolution"]
    assert (
        c.backbone.train.lr == d["backbone"]["train"]["lr"]
        and c.frng.saliency.box_size == d["frng"]["saliency"]["box_size"]
    )
    assert as_dict(c) == d and as_dict(d) is d
    assert digests.rule_digest(c.to_dict(), "train") == digests.rule_digest(d, "train")
    with pytest.raises(dataclasses.FrozenInstanceError):
        c.train.steps = 1  # type: ignore[misc]


def test_config_module_stays_torch_free():
    """frng.plan.config, frng.plan.digests (and the planning helpers the rule files call with the dict) import no torch."""
    code = (
        "import sys, frng.plan.config as fc, frng.plan.digests, frng.plan.catalog as cat, frng.plan.variants as v; "
        "d = fc.load('config/smoke.yaml'); cat.plan(d); v.runs(d); print('torch' in sys.modules)"
    )
    out = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"


def test_every_config_from_dict_is_strict():
    """No lenient copy is left: every ``from_dict`` of a config dataclass builds through frng.plan.sections.section (or inherits frng.plan.sections.Settings's) (the
    one exception, IntrinsicPriors.from_dict, reads tensors, not a config), and nothing filters keys by the
    dataclass's fields."""
    import re

    lenient, not_strict = [], []
    for f in sorted((ROOT / "frng").rglob("*.py")):
        text = f.read_text()
        if "__dataclass_fields__" in text:
            lenient.append(str(f.relative_to(ROOT)))
        for m in re.finditer(r"def from_dict\(cls[^\n]*\n((?:[ \t]+[^\n]*\n){1,6})", text):
            if "section(" not in m.group(1) and "IntrinsicPriors" not in m.group(0):
                not_strict.append(f"{f.relative_to(ROOT)}: {m.group(0).splitlines()[0].strip()}")
    assert not lenient and not not_strict, (lenient, not_strict)


# constructors besides from_dict, and why: a saved model's or asset's shading record, whose keys added later take
# frng.render.shading.SAVED_DEFAULTS (what the model was trained with), not the schema's defaults
OTHER_CONSTRUCTORS = {("shading", "from_saved")}


def test_one_constructor_per_section():
    """A section is built one way from its mapping, ``cls.from_dict`` (given by frng.plan.sections.register, strict, at
    the key the class is registered under), and one way from the whole config, frng.plan.sections.config_section."""
    config = fc.load(ROOT / "config" / "config.yaml")
    for where, cls in SECTIONS.items():
        assert "from_dict" in vars(cls), f"{where}: {cls.__name__} has no from_dict of its registration"
        others = {
            (where, name)
            for klass in cls.__mro__
            for name, v in vars(klass).items()
            if isinstance(v, (classmethod, staticmethod)) and name != "from_dict"
        }
        assert others <= OTHER_CONSTRUCTORS, f"{where}: constructors besides from_dict: {sorted(others)}"
        mapping = config
        for part in where.split(".") if where else ():
            mapping = mapping[part]
        assert cls.from_dict(mapping) == section(cls, mapping, where), where
    shading = SECTIONS["shading"].from_dict({"spp_infer": 8})
    assert shading == config_section({"shading": {"spp_infer": 8}}, "shading")
    with pytest.raises(ConfigError, match=r"^shading\.bogus: unknown key"):
        SECTIONS["shading"].from_dict({"bogus": 1})
    with pytest.raises(ValueError, match="given by register"):
        register("raster")(type("RasterConfig", (), {"from_dict": classmethod(lambda c, d: None)}))
