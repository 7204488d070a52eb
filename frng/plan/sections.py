"""Typed config sections: the frozen dataclass of a config section, built strictly from its mapping, and the one
declaration of every config key.

A leaf module (it imports no frng module): every component declares the dataclass of the section it reads beside its
own code and registers it here by its dotted schema key (:func:`register`), so nothing here names a component.
Each config key is declared once, on its section's field, with :func:`key`: its default, its JSON-schema constraints
and what it means. ``config/schema.yaml`` and the key tables of ``config/README.md`` are generated from those
declarations (:mod:`frng.plan.schema_gen`, ``make config-docs``; tests/test_config_declared.py fails when they drift).
A section's own description is its class's ``CONFIG_DOC``.

Building a section is strict (:func:`section`): an unknown key is a :class:`ConfigError` naming it, a missing key
takes its field's declared default. A class may hold fields that are no config keys ("internal" fields: values the
code sets, e.g. SaliencyConfig.top_k from frng.top_k_percent, the IDM trainer's fixed weight decay); those keep a
Python default or are always passed, are declared without :func:`key`, and are not part of the config
(:func:`section_dict` leaves them out).

The architecture records stored in model files (BackboneConfig, IDMConfig, FRNGConfig) and the module settings
derived from them (:class:`Settings`: MaterialFormerConfig, FineGeometryConfig, GaussianDecodeConfig,
LightIndependenceConfig) map to no section; they are built with the same helper, so a model file's ``config`` with a
key the code does not know (or without one it needs) fails, naming it (a record takes no declared default).

The whole typed config (``frng.typedconfig.Config``, one section per top-level key) is assembled where every
section's class is imported: the stages build it once and hand each library its section(s).
"""

from __future__ import annotations

import copy
import dataclasses
import functools
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import yaml

SCHEMA_PATH = Path(__file__).resolve().parents[2] / "config" / "schema.yaml"


class ConfigError(ValueError):
    """A config value is invalid. The message starts with the dotted key path."""


def load_schema(path: Path | str = SCHEMA_PATH) -> dict:
    with open(path) as f:
        return yaml.safe_load(f)


@functools.lru_cache(maxsize=1)
def _schema() -> dict:
    return load_schema()


def schema_node(where: str | None) -> dict:
    """The schema of the section at dotted key ``where`` ("" or None = the whole config)."""
    node = _schema()
    for part in where.split(".") if where else ():
        node = node["properties"][part]
    return node


def schema_bounds(schema: Mapping, sections: tuple[str, ...]) -> dict[str, tuple[float | None, float | None]]:
    """Key name -> (minimum, maximum) of the number keys of the config schema's ``sections`` (dotted; a name in
    several: the loosest bounds), from ``minimum`` / ``exclusiveMinimum`` / ``maximum`` / ``exclusiveMaximum``."""
    out: dict[str, tuple[float | None, float | None]] = {}
    for where in sections:
        node = schema
        for part in where.split("."):
            node = (node.get("properties") or {}).get(part) or {}
        for name, sub in (node.get("properties") or {}).items():
            if not isinstance(sub, Mapping):
                continue
            lo = sub.get("minimum", sub.get("exclusiveMinimum"))
            hi = sub.get("maximum", sub.get("exclusiveMaximum"))
            if name in out:
                a, b = out[name]
                lo = None if a is None or lo is None else min(a, lo)
                hi = None if b is None or hi is None else max(b, hi)
            out[name] = (lo, hi)
    return out


ARCHITECTURE_SECTIONS = ("frng", "backbone", "idm", "shading", "raster", "model")  # schema sections a model records


@functools.lru_cache(maxsize=1)
def architecture_bounds() -> dict[str, tuple[float | None, float | None]]:
    """Key name -> (None, maximum) over :data:`ARCHITECTURE_SECTIONS`: what a model file's architecture record is
    checked against before a model is built from it (:func:`frng.io.check_architecture`). The schema's maxima only:
    an ablation's record holds sizes below the config's minima (no-idm: prior_dim 0)."""
    return {k: (None, hi) for k, (_, hi) in schema_bounds(_schema(), ARCHITECTURE_SECTIONS).items()}


def schema_keys(where: str) -> list[str]:
    """The keys of the schema's section at dotted key ``where`` ("" = the top level)."""
    return list(schema_node(where).get("properties", {}))


def schema_defaults(where: str) -> dict[str, Any]:
    """The schema's defaults of the section at dotted key ``where`` (deep copies; the declared defaults, as
    config/schema.yaml is generated from the declarations)."""
    props = schema_node(where).get("properties", {})
    return {k: copy.deepcopy(v["default"]) for k, v in props.items() if "default" in v}


# -- declaring a config key ----------------------------------------------------------------------------------------


class _Required:
    def __repr__(self) -> str:
        return "REQUIRED"


REQUIRED: Any = _Required()
"""The default of a key every config must set (``objects.count``, ``render.resolution``, ``tier``)."""

FINITE: dict = {"not": {"minimum": 1, "maximum": 0}}
"""JSON-schema fragment that refuses NaN: every comparison with NaN is false, so only NaN satisfies "at least 1 and at
most 0", and the ``not`` rejects it (``key(0.001, ..., **FINITE)``)."""

CONFIG = "config"
"""The field-metadata entry of a declared config key (:func:`key`)."""


def key(default: Any = REQUIRED, doc: str = "", *, required: bool = False, **schema: Any) -> Any:
    """Declare a section dataclass field as a config key: its ``default`` (:data:`REQUIRED`: the config must set it;
    a section field: ``{}``), ``doc`` -- what the key means (the schema's description and the README table's
    meaning) -- and its JSON-schema constraints as keywords (``type``, ``minimum``, ``enum``, ``items``, ...; a list's
    or a plain mapping's whole schema fragment; ``**FINITE`` refuses NaN). ``required``: the config must name it even
    though it has a default. The field itself has no Python default: :func:`section` fills a missing key from here."""
    meta = {"default": default, "doc": " ".join(doc.split()), "required": required or default is REQUIRED}
    return dataclasses.field(metadata={CONFIG: {**meta, "schema": schema}})


def declaration(f: dataclasses.Field) -> dict | None:
    """The :func:`key` declaration of a dataclass field (default, doc, required, schema); None for an internal
    field."""
    return f.metadata.get(CONFIG)


def declared_default(f: dataclasses.Field) -> Any:
    """A deep copy of a declared field's default (:data:`REQUIRED` when it has none)."""
    default = declaration(f)["default"]
    return default if default is REQUIRED else copy.deepcopy(default)


# -- the registry: dotted schema key -> the dataclass that holds that section ---------------------------------------

SECTIONS: dict[str, type] = {}
"""Dotted schema key of every object-valued config section ("" = the whole config) -> the frozen dataclass that holds
it, filled in by :func:`register` as the components' modules are imported (``frng.typedconfig`` imports them all).
Sections not registered (objects.material_mix) and list items (objects.extra, envmaps.extra) stay plain values."""


def register(where: str):
    """Class decorator: ``cls`` holds the config section at dotted key ``where``, and gets its one constructor,
    ``cls.from_dict(mapping)``: strict (:func:`section` at ``where``: an unknown key is an error naming it, a missing
    one takes its declared default; ``{}`` or None: the defaults). A section of the whole config is
    :func:`config_section` (the stages: ``typed(config).<key>``); a class spells no constructor of its own."""

    def deco(cls: type) -> type:
        known = SECTIONS.get(where)
        if known is not None and known.__qualname__ != cls.__qualname__:
            raise ValueError(f"config section '{where}': registered twice ({known.__name__}, {cls.__name__})")
        if "from_dict" in vars(cls):
            raise ValueError(f"config section '{where}': {cls.__name__}.from_dict is given by register, not spelled")
        SECTIONS[where] = cls
        cls.from_dict = classmethod(lambda c, d=None: section(c, d, where))
        return cls

    return deco


def _dotted(where: str | None, key: str) -> str:
    return f"{where}.{key}" if where else key


def _frozen_value(value: Any) -> Any:
    """Lists become tuples (a frozen section holds no list); dicts and scalars stay."""
    return tuple(_frozen_value(v) for v in value) if isinstance(value, list) else value


def _nested_class(key: str) -> type | None:
    """The registered class of the section at ``key``; None for a mapping that is a plain value. A schema section
    with keys of its own (``properties``) and no class registered is an error (its module was not imported)."""
    cls = SECTIONS.get(key)
    if cls is None and key in section_keys():
        raise ConfigError(f"{key}: no section class registered (import the module that declares it)")
    return cls


PLAIN_MAPPINGS = frozenset({"objects.material_mix", "objects.objaverse.filter"})
"""Object-valued schema keys that stay plain mappings (a table of fractions, a filter's free-form fields): every other
object with keys of its own is a section with a registered class (tests/test_config_typed.py)."""


@functools.lru_cache(maxsize=1)
def section_keys() -> tuple[str, ...]:
    """Dotted keys of every object section of the schema (an object with keys of its own, but
    :data:`PLAIN_MAPPINGS`), in the schema's order, "" (the whole config) first: each has a registered class."""
    out = [""]

    def walk(node: dict, prefix: str) -> None:
        for name, sub in (node.get("properties") or {}).items():
            key = _dotted(prefix, name)
            if isinstance(sub, dict) and sub.get("properties") and key not in PLAIN_MAPPINGS:
                out.append(key)
                walk(sub, key)

    walk(_schema(), "")
    return tuple(out)


def section(cls: type, d: Mapping | None, where: str | None = None):
    """Build the dataclass ``cls`` from the mapping ``d`` strictly.

    ``where``: the dotted schema key the mapping is (``"train"``, ``"backbone.train"``; None for a class that maps
    to no section, e.g. a model file's architecture record). A key of ``d`` that is no field of ``cls`` raises
    :class:`ConfigError` naming it (``train.stepz: unknown key; known: ...``); a missing field takes its declared
    default (:func:`key`; sections only), else its dataclass default (internal fields only), else raises naming it. A field whose
    dotted key is a registered section (:data:`SECTIONS`) is built from its mapping the same way; lists become
    tuples.
    """
    d = dict(d or {})
    names = [f.name for f in dataclasses.fields(cls)]
    unknown = sorted(set(d) - set(names), key=str)
    label = where if where is not None else cls.__name__
    if unknown:
        raise ConfigError(f"{_dotted(label, str(unknown[0]))}: unknown key; known: {', '.join(sorted(names))}")
    kwargs = {}
    for f in dataclasses.fields(cls):
        if f.name in d:
            value = d[f.name]
        elif where is not None and declaration(f) is not None and declared_default(f) is not REQUIRED:
            value = declared_default(f)
        elif f.default is not dataclasses.MISSING or f.default_factory is not dataclasses.MISSING:
            continue
        else:
            raise ConfigError(f"{_dotted(label, f.name)}: missing key")
        if where is not None and isinstance(value, Mapping):
            nested = _nested_class(_dotted(where, f.name))
            if nested is not None:
                value = section(nested, value, _dotted(where, f.name))
        kwargs[f.name] = _frozen_value(value)
    return cls(**kwargs)


def _plain(value: Any) -> Any:
    if isinstance(value, (tuple, list)):
        return [_plain(v) for v in value]
    if isinstance(value, Mapping):
        return {k: _plain(v) for k, v in value.items()}
    return copy.deepcopy(value)


def section_dict(obj, where: str) -> dict:
    """The config mapping of a section dataclass ``obj`` at dotted key ``where``: its schema keys only (internal
    fields left out), in the schema's order, nested sections as mappings, tuples as lists."""
    out = {}
    for key in schema_keys(where):
        value = getattr(obj, key)
        if dataclasses.is_dataclass(value):
            value = section_dict(value, _dotted(where, key))
        out[key] = _plain(value)
    return out


class Settings:
    """Mixin of a module's settings dataclass that maps to no config section (the pipeline sets every field; their
    defaults serve direct use: tests, notebooks): strict :meth:`from_dict` (unknown keys are errors, missing keys take
    the field defaults) and :meth:`to_dict`."""

    @classmethod
    def from_dict(cls, d: Mapping):
        return section(cls, d)

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)


# -- the config as the torch-free planning helpers receive it ---------------------------------------------------------
#
# The Snakemake rule files keep the validated dict, and the helpers they call while planning (frng.plan.catalog,
# frng.plan.variants), which must not import torch, take it as well as the typed config that the stages hand them.


def is_typed(config: Any) -> bool:
    """Whether ``config`` is the typed config (a dataclass), not the validated mapping."""
    return dataclasses.is_dataclass(config) and not isinstance(config, type)


def config_section(config: Any, key: str):
    """The top-level entry ``key`` of the typed config, or of a config mapping: a section is built from it
    (:func:`section`; the mapping may be partial: missing keys take the declared defaults), a scalar (``seed``,
    ``results``, ...) is returned as it is. Only that section's class is needed (registered by the caller's own
    module): the planning helpers stay torch-free."""
    if is_typed(config):
        return getattr(config, key)
    if key not in SECTIONS:
        return config[key]
    return section(SECTIONS[key], config.get(key, {}), key)


def as_dict(config: Any) -> Mapping:
    """The config mapping of the typed config (or the mapping itself)."""
    return config.to_dict() if is_typed(config) else config


TypedConfig = Any
"""How a library annotates the whole typed config (``frng.typedconfig.Config``): libraries do not import
``frng.typedconfig`` (it imports every component that declares a section). Library functions take the sections
they read (their classes) and small typed arguments, not the whole config; what still takes it: the section
selectors a stage calls (:func:`config_section`, ``frng.training.frng_trainer.ModelSections.of``, ``frng.apps.relight.RelightJob.of``)
and the torch-free planning helpers of :mod:`frng.plan.catalog` and :mod:`frng.plan.variants` (the dataset plan, the
variants and runs follow from many sections; the rule files call them with the validated dict)."""
