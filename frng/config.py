"""Loading and validating pipeline configs (``config/*.yaml`` against ``config/schema.yaml``).

One implementation serves both the workflow (``rules/common.smk`` calls :func:`validate`) and the CLI
(stages call :func:`load`), so a bad config fails the same way everywhere, before any job runs,
with a message naming the offending key.

Validation is JSON Schema 2020-12 (structure, types, ranges, unknown keys) with defaults from the
schema filled in, followed by cross-key checks that a schema cannot express (see :func:`check_semantics`).
"""

from __future__ import annotations

import argparse
import copy
import dataclasses
import functools
import hashlib
import importlib
import json
import os
import re
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import yaml

if TYPE_CHECKING:  # the sections' classes live beside the code that reads them; typed() imports them
    from frng.data.catalog import EnvmapsConfig, ObjectsConfig, RenderConfig
    from frng.metrics import EvalConfig
    from frng.model.frng import FRNGSection
    from frng.model.train import TrainConfig
    from frng.nn import ModelConfig
    from frng.priors.backbone import BackboneSection
    from frng.priors.idm import IDMSection
    from frng.render.raster import RasterConfig
    from frng.render.shading import ShadingConfig

SCHEMA_PATH = Path(__file__).resolve().parent.parent / "config" / "schema.yaml"


class ConfigError(ValueError):
    """A config value is invalid. The message starts with the dotted key path."""


def _key(path) -> str:
    parts = [str(p) if not isinstance(p, int) else f"[{p}]" for p in path]
    return ".".join(parts).replace(".[", "[") or "<root>"


def load_schema(path: Path | str = SCHEMA_PATH) -> dict:
    with open(path) as f:
        return yaml.safe_load(f)


@functools.lru_cache(maxsize=1)
def _schema() -> dict:
    return load_schema()


def _validator_with_defaults(schema: dict):
    from jsonschema import Draft202012Validator, validators

    base = Draft202012Validator

    def set_defaults(validator, properties, instance, schema_):
        if isinstance(instance, dict):
            for name, sub in properties.items():
                if "default" in sub and name not in instance:
                    instance[name] = copy.deepcopy(sub["default"])
        yield from base.VALIDATORS["properties"](validator, properties, instance, schema_)

    # JSON Schema's "integer" accepts 32.0 (a float with zero fraction); a config's integers must be ints (a
    # float resolution reaches Blender and numpy shapes). Booleans are not integers either.
    type_checker = base.TYPE_CHECKER.redefine(
        "integer", lambda checker, instance: isinstance(instance, int) and not isinstance(instance, bool)
    )
    cls = validators.extend(base, {"properties": set_defaults}, type_checker=type_checker)
    return cls(schema)


def validate(config: dict, schema: dict | None = None) -> dict:
    """Validate ``config`` in place (defaults filled in) and return it.

    Raises :class:`ConfigError` naming the first offending key.
    """
    schema = schema if schema is not None else load_schema()
    validator = _validator_with_defaults(schema)
    errors = sorted(validator.iter_errors(config), key=lambda e: (len(e.absolute_path), str(e.absolute_path)))
    if errors:
        err = errors[0]
        path = list(err.absolute_path)
        if err.validator == "additionalProperties":
            extra = sorted(set(err.instance) - set(err.schema.get("properties", {})))
            path = path + extra[:1]
            msg = f"unknown key (allowed: {', '.join(sorted(err.schema.get('properties', {})))})"
        else:
            msg = err.message
        raise ConfigError(f"config key '{_key(path)}': {msg}")
    check_semantics(config)
    return config


def check_semantics(config: dict) -> None:
    """Cross-key rules that JSON Schema cannot state."""
    patch = config["model"]["patch_size"]
    res = config["render"]["resolution"]
    if res % patch:
        raise ConfigError(f"config key 'render.resolution': {res} is not a multiple of model.patch_size ({patch})")
    objects = config["objects"]
    extra = objects.get("extra", [])
    n_train = objects["count"] - objects["test_count"] + sum(e["split"] == "train" for e in extra)
    n_test = objects["test_count"] + sum(e["split"] == "test" for e in extra)
    if objects["test_count"] > objects["count"]:
        raise ConfigError(
            f"config key 'objects.test_count': {objects['test_count']} exceeds objects.count={objects['count']}"
        )
    if n_train < 1:
        raise ConfigError(
            f"config key 'objects.count': {objects['count']} objects with test_count={objects['test_count']} "
            "leave no training object"
        )
    if n_test < 1:
        raise ConfigError("config key 'objects.test_count': the evaluation needs at least one test object")
    mix = objects["material_mix"]
    if abs(sum(mix.values()) - 1.0) > 1e-6:
        raise ConfigError(f"config key 'objects.material_mix': fractions sum to {sum(mix.values()):.3f}, not 1")
    shading = config.get("shading", {})
    if "spp_grad" in shading and "spp_train" in shading and shading["spp_grad"] > shading["spp_train"]:
        raise ConfigError(
            f"config key 'shading.spp_grad': {shading['spp_grad']} exceeds shading.spp_train="
            f"{shading['spp_train']} (the samples with gradients are a subset of the training samples)"
        )
    backbone = config.get("backbone", {})
    if "near" in backbone and "far" in backbone and backbone["near"] >= backbone["far"]:
        raise ConfigError(f"config key 'backbone.near': {backbone['near']} is not below backbone.far={backbone['far']}")
    check_results_path(config.get("results", "results"))


# Characters a results path may not hold: control characters (newlines end shell commands and log lines) and
# braces (Snakemake reads them as wildcards in every output path). Spaces, quotes and other shell characters are
# fine: the rules quote every path they put into a shell command (`{...:q}`).
_BAD_PATH_CHARS = re.compile(r"[\x00-\x1f\x7f{}]")


def check_results_path(results) -> None:
    if not isinstance(results, str) or not results.strip():
        raise ConfigError(f"config key 'results': {results!r} is not a folder path")
    bad = _BAD_PATH_CHARS.search(results)
    if bad:
        raise ConfigError(
            f"config key 'results': {results!r} holds {bad.group()!r}; a results path may not hold "
            f"control characters or braces (Snakemake reads braces as wildcards)"
        )


def read_yaml(path: Path | str) -> dict:
    """Read a config YAML file as a mapping (no validation).

    Raises :class:`ConfigError` naming the file (and the line of a YAML syntax error) when the file is missing,
    unreadable, not YAML, or not a mapping at the top level."""
    path = Path(path)
    if not path.exists():
        raise ConfigError(f"config file {path} does not exist")
    if not path.is_file():
        raise ConfigError(f"config file {path} is not a file")
    try:
        text = path.read_text()
    except OSError as e:
        raise ConfigError(f"config file {path}: cannot read ({e.strerror})") from e
    try:
        config = yaml.safe_load(text)
    except yaml.YAMLError as e:
        mark = getattr(e, "problem_mark", None) or getattr(e, "context_mark", None)
        where = f", line {mark.line + 1} column {mark.column + 1}" if mark is not None else ""
        problem = getattr(e, "problem", None) or str(e).splitlines()[0]
        raise ConfigError(f"config file {path}{where}: invalid YAML ({problem})") from e
    config = {} if config is None else config
    if not isinstance(config, dict):
        raise ConfigError(f"config file {path}: top level must be a mapping")
    return config


def load(path: Path | str, overrides: dict | None = None) -> dict:
    """Read a YAML config, apply ``overrides`` (nested dict, merged), validate, fill defaults."""
    config = read_yaml(path)
    if overrides:
        config = merge(config, overrides)
    return validate(config)


def merge(base: dict, override: dict) -> dict:
    """Recursive dict merge (override wins); returns a new dict."""
    out = copy.deepcopy(base)
    for k, v in override.items():
        if isinstance(v, dict) and isinstance(out.get(k), dict):
            out[k] = merge(out[k], v)
        else:
            out[k] = copy.deepcopy(v)
    return out


# -- the effective config of a results folder ------------------------------------------------------
#
# Every stage reads ``{results}/config.yaml``: the validated config (defaults filled in) of the run that made the
# folder. The workflow writes it when jobs start (rules/common.smk, ``onstart:``), never while planning, and
# refuses to run with a different config unless asked to replace it (:data:`OVERWRITE_SWITCH`).

OVERWRITE_SWITCH = "overwrite_config"
"""``snakemake --config overwrite_config=true``: replace a results folder's recorded config that differs."""

_TRUE = {"true", "yes", "1", "on"}
_FALSE = {"false", "no", "0", "off", "none", ""}


def pop_switch(config: dict, name: str = OVERWRITE_SWITCH) -> bool:
    """Remove the workflow switch ``name`` from ``config`` (it is not part of the effective config) and return
    its value as a bool. Raises :class:`ConfigError` for a value that is not a boolean."""
    value = config.pop(name, False)
    if isinstance(value, bool):
        return value
    if value is None or str(value).strip().lower() in _FALSE:
        return False
    if str(value).strip().lower() in _TRUE:
        return True
    raise ConfigError(f"config key '{name}': {value!r} is not a boolean (use true or false)")


def flatten(config: dict, prefix: str = "") -> dict[str, Any]:
    """Nested mapping -> {dotted key: leaf value} (lists and empty mappings are leaves)."""
    out: dict[str, Any] = {}
    for k, v in config.items():
        if isinstance(v, dict) and v:
            out.update(flatten(v, f"{prefix}{k}."))
        else:
            out[f"{prefix}{k}"] = v
    return out


_ABSENT = "<absent>"


def differences(recorded: dict, effective: dict) -> list[str]:
    """The keys whose values differ between two configs, as ``"key: recorded R, now E"`` lines (sorted)."""
    a, b = flatten(recorded), flatten(effective)
    return [
        f"{k}: recorded {a.get(k, _ABSENT)!r}, now {b.get(k, _ABSENT)!r}"
        for k in sorted(set(a) | set(b))
        if a.get(k, _ABSENT) != b.get(k, _ABSENT)
    ]


def read_recorded(path: Path | str) -> dict | None:
    """The config recorded in a results folder (``{results}/config.yaml``), or None when there is none yet."""
    path = Path(path)
    if not path.exists():
        return None
    return read_yaml(path)


def _write_text_atomic(path: Path, text: str) -> None:
    """Write ``text`` to ``path`` through a temporary name beside it (created with the umask's permissions).
    Raises :class:`ConfigError` naming the file when the folder cannot be written."""
    tmp = path.with_name(f".tmp-{path.name}.{os.getpid()}")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp.write_text(text)
        os.replace(tmp, path)
    except OSError as e:
        raise ConfigError(f"cannot write {path}: {e.strerror or e}") from e
    finally:
        if tmp.exists():
            tmp.unlink()


def check_writable(folder: Path | str) -> None:
    """Raise :class:`ConfigError` naming ``folder`` when it (or, while it does not exist yet, its nearest existing
    parent) cannot be written: a read-only results folder fails here, in one line, before any job starts."""
    folder = Path(folder).absolute()
    existing = next(p for p in (folder, *folder.parents) if p.exists())
    if not existing.is_dir() or not os.access(existing, os.W_OK | os.X_OK):
        what = "" if existing == folder else f" (its parent {existing} cannot be written)"
        raise ConfigError(f"results folder {folder} is not writable{what}")


def dump(config: dict) -> str:
    """The YAML text of a config as recorded and as ``frng config`` prints it."""
    return yaml.safe_dump(config, sort_keys=False)


def record(config: dict, path: Path | str, overwrite: bool = False) -> str:
    """Record the validated ``config`` as the effective config of its results folder at ``path``.

    Returns ``"written"`` (none was recorded), ``"unchanged"`` (the same config is recorded; the file is not
    touched, so its mtime stays) or ``"replaced"`` (a different one was recorded and ``overwrite`` is set).
    Raises :class:`ConfigError` when a different config is recorded and ``overwrite`` is not set (listing the
    differing keys), or when the file cannot be read or written."""
    path = Path(path)
    check_writable(path.parent)
    try:
        recorded = read_recorded(path)
    except ConfigError as e:  # an unreadable record: only an explicit overwrite replaces it
        if not overwrite:
            raise ConfigError(
                f"recorded config: {e}; rerun with `--config {OVERWRITE_SWITCH}=true` to replace it"
            ) from e
        recorded = {}
    if recorded is not None:
        diff = differences(recorded, config)
        if not diff:
            return "unchanged"
        if not overwrite:
            raise ConfigError(refusal(path, diff))
    _write_text_atomic(path, dump(config))
    return "written" if recorded is None else "replaced"


def refusal(path: Path | str, diff: list[str], shown: int = 8) -> str:
    """The message refusing to run a config that differs from the one recorded at ``path``."""
    more = f"; ... ({len(diff) - shown} more)" if len(diff) > shown else ""
    return (
        f"{path} records a different config ({len(diff)} key(s) differ: {'; '.join(diff[:shown])}{more}). "
        f"The results in that folder were made with the recorded config: point `results:` at a new folder, "
        f"or rerun with `--config {OVERWRITE_SWITCH}=true` to replace the recorded config (results already "
        f"there are not rebuilt unless their rules rerun)"
    )


# -- what each rule reads: the config digests that rerun it -----------------------------------------
#
# Every rule of the workflow declares ``params: config_digest=rule_digest(config, "<rule>")``: a digest of exactly
# the config keys its stage reads (below). Snakemake's ``params`` rerun trigger then reruns a rule whose keys were
# edited, and its downstream rules because their inputs are rebuilt; the other rules stay. A key is a dotted path
# (a whole section or one leaf); ``"!section.key"`` removes a part of a section listed before it. Missing keys
# digest as null. ``results`` and the overwrite switch are never part of a digest.
#
# The lists follow what each stage's entry point reads (``config[...]``, ``X.from_config(config)``, helpers
# included). A key a stage reads but its list lacks leaves stale results; a key listed needlessly only costs an
# extra rerun. Sections an upstream rule already covers may be listed whole downstream at no cost (editing them
# reruns the upstream rule, hence this one).

PLAN_KEYS: tuple[str, ...] = ("seed", "objects", "envmaps", "render.input_lights", "render.target_lights")
"""What the dataset plan reads (frng/data/catalog.py ``plan``): env maps and their split, objects, their split,
materials and lights. Every stage that asks the plan for a split or the object list reads these."""

ENVMAP_PLAN_KEYS: tuple[str, ...] = ("seed", "envmaps")
"""What the env-map plan reads (frng/data/catalog.py ``envmap_plan``)."""

# idm.* keys only the diffusion-renderer IDM reads (frng/priors/__init__.py), plus idm.kind: not the learned IDM's
# architecture or training
_IDM_NOT_TRAINED = ("!idm.kind", "!idm.diffusion_renderer_dir", "!idm.normal_space", "!idm.depth_invert")

RULE_CONFIG_KEYS: dict[str, tuple[str, ...]] = {
    # frng/data/envmaps.py: the env-map plan, envmaps.width/normalize, Blender threads of the sky bakes
    "envmaps": (*ENVMAP_PLAN_KEYS, "render.threads"),
    # frng/data/curate.py: render.* (rig, Cycles, fur) and envmaps.width; the object's own plan entry (its split,
    # mesh, material, seed and lights) is the rule's `spec` param, so adding an object reruns no other curation
    "curate": ("render", "envmaps.width"),
    # frng/data/preview.py: the plan's object ids
    "dataset_preview": PLAN_KEYS,
    # frng/priors/backbone_train.py: the training split, architecture + backbone.train, patch size, the models'
    # seed (frng.training.train_seed: train_seed, else seed), device
    "backbone_train": (
        *PLAN_KEYS,
        "train_seed",
        "device",
        "backbone",
        "!backbone.cache_extra_lights",
        "model.patch_size",
    ),
    # frng/priors/idm_train.py: the training split, the learned IDM's architecture + idm.train, near/far, patch
    # size, the models' seed, device
    "idm_train": (
        *PLAN_KEYS,
        "train_seed",
        "device",
        "idm",
        *_IDM_NOT_TRAINED,
        "model.patch_size",
        "backbone.near",
        "backbone.far",
    ),
    # frng/priors/cache.py (backbone model from its file): extra training lights from the env-map plan, DDIM seeds
    "backbone_cache": (*ENVMAP_PLAN_KEYS, "device", "backbone.cache_extra_lights"),
    # frng/priors/cache.py + build_idm (learned IDM from its file): idm.kind and the diffusion-renderer settings
    "idm_priors": ("device", "idm", "!idm.train", "backbone.near", "backbone.far"),
    # frng/priors/evaluate.py: both splits, build_idm, seeds (backbone model from its file)
    "eval_backbone": (*PLAN_KEYS, "device", "idm", "!idm.train", "backbone.near", "backbone.far"),
    # rules/train.smk: indexes of the training split's files
    "training_set_caches": PLAN_KEYS,
    "training_set_priors": PLAN_KEYS,
    # frng/model/train.py + variant_config: train.*, the architecture (frng.* but the variant lists), decoder and
    # training shading (not the inference-only spp_infer / bf16_infer: relight takes those from the config),
    # rasterizer, idm.kind (which priors file), the training split, the models' seed, device
    "train": (
        *PLAN_KEYS,
        "train_seed",
        "device",
        "train",
        "!train.seeds",
        "frng",
        "!frng.variants",
        "!frng.k_sweep",
        "model.patch_size",
        "shading",
        "!shading.spp_infer",
        "!shading.bf16_infer",
        "raster",
        "idm.kind",
    ),
    # a copy of the full model: which K-sweep entry is the full model
    "model_alias": ("frng.top_k_percent",),
    # frng/relight.py: the runs (frng.*, idm.kind, render.extra_input_views, train.seeds), resolution check, split check,
    # build_idm, shading.spp_infer + inference shading, seeds, device
    "relight": (
        *PLAN_KEYS,
        "device",
        "render.resolution",
        "render.extra_input_views",
        "idm",
        "!idm.train",
        "backbone.near",
        "backbone.far",
        "shading",
        "frng",
        "train.seeds",
        "train_seed",
    ),
    # frng/stages/evaluate.py: eval.protocol/background and the planned runs (frng/variants.py: the variants, the
    # training seeds, whether the Lambertian-base run exists)
    "evaluate": (
        "eval",
        "frng",
        "idm.kind",
        "render.extra_input_views",
        "train.seeds",
        "train_seed",
        "seed",
        "shading.decoder_cosine",
    ),
    # frng/report/paper_tables.py: tier and eval.background in the captions
    "tables": ("tier", "eval"),
    # frng/report/paper_figures.py: patch size (saliency), the ablation variants
    "figures": ("model.patch_size", "frng.variants"),
    # frng/benchmarks (rules/benchmarks.smk): the import converts to the resolution, map width and input-view count;
    # relighting an imported object reads what `relight` reads; the benchmark table reads the runs and eval
    "import_benchmark": ("benchmarks", "render.resolution", "render.extra_input_views", "envmaps.width"),
    "relight_benchmark": (
        "device",
        "render.resolution",
        "render.extra_input_views",
        "idm",
        "!idm.train",
        "backbone.near",
        "backbone.far",
        "shading",
        "frng",
        "train.seeds",
        "train_seed",
        "seed",
    ),
    "evaluate_benchmarks": ("benchmarks", "eval", "tier"),
}
"""Rule name -> the config keys its stage reads (see the comment above)."""

RULES_WITHOUT_DIGEST = frozenset({"all", "config_digest"})
"""Rules that run no stage (``config_digest`` records the others' digests in the results folder)."""

_NEVER_DIGESTED = ("results", OVERWRITE_SWITCH)


def _lookup(config: Any, dotted: str) -> Any:
    node = config
    for part in dotted.split("."):
        if not isinstance(node, dict) or part not in node:
            return None
        node = node[part]
    return node


def config_digest(config: dict, keys, length: int = 16) -> str:
    """A short stable digest (sha256 of canonical JSON, ``length`` hex digits) of the config ``keys``: dotted keys
    or sections, each ``"!key"`` removing a part of a section listed. Key order does not matter; a missing key
    digests as null."""
    keys = list(keys)
    include = sorted({k for k in keys if not k.startswith("!")})
    selected = {k: copy.deepcopy(_lookup(config, k)) for k in include}
    for ex in sorted({k[1:] for k in keys if k.startswith("!")}):
        owners = [k for k in include if ex.startswith(k + ".")]
        if not owners:
            raise ValueError(f"config digest: '!{ex}' removes a key no listed section contains")
        for k in owners:
            node, *rest = selected[k], *ex[len(k) + 1 :].split(".")
            for part in rest[:-1]:
                node = node.get(part) if isinstance(node, dict) else None
            if isinstance(node, dict):
                node.pop(rest[-1], None)
    text = json.dumps(selected, sort_keys=True, separators=(",", ":"), default=str)
    return hashlib.sha256(text.encode()).hexdigest()[:length]


def rule_digest(config: dict, rule: str) -> str:
    """The digest of the config keys rule ``rule`` reads (:data:`RULE_CONFIG_KEYS`): its ``config_digest`` param."""
    if rule not in RULE_CONFIG_KEYS:
        raise ConfigError(f"rule {rule!r} has no entry in frng.config.RULE_CONFIG_KEYS (the config keys it reads)")
    return config_digest(config, RULE_CONFIG_KEYS[rule])


def write_rule_digest(config: dict, rule: str, path: str | os.PathLike, log: str | os.PathLike | None = None) -> Path:
    """Write ``path`` (``{results}/.digests/{rule}-{digest}.txt``, :meth:`frng.layout.Layout.rule_digest`): the keys
    rule ``rule`` reads, their values and digest; and remove the rule's other digest files, so that going back to
    an earlier config finds its file missing again (and reruns the rule). ``log``: where to say so."""
    from frng import io

    path = Path(path)
    digest = rule_digest(config, rule)
    if path.name != f"{rule}-{digest}.txt":
        raise ConfigError(f"{path}: not the digest file of rule {rule} for this config ({rule}-{digest}.txt)")
    keys = RULE_CONFIG_KEYS[rule]
    io.write_json(
        path,
        {
            "rule": rule,
            "digest": digest,
            "keys": list(keys),
            "values": {k: _lookup(config, k) for k in keys if not k.startswith("!")},
        },
    )
    for other in path.parent.glob(f"{rule}-*.txt"):
        if other != path and re.fullmatch(rf"{re.escape(rule)}-[0-9a-f]+\.txt", other.name):
            other.unlink(missing_ok=True)
    if log is not None:
        Path(log).parent.mkdir(parents=True, exist_ok=True)
        Path(log).write_text(f"recorded {path}\n")
    return path


def remove_stale_digests(config: dict, folder: str | os.PathLike) -> list[Path]:
    """Remove the digest files ``{folder}/{rule}-{digest}.txt`` of other configs (a run that touched its jobs,
    ``--touch``, leaves them): called when jobs start, never while planning. Returns the files removed."""
    current = {f"{rule}-{rule_digest(config, rule)}.txt" for rule in RULE_CONFIG_KEYS}
    folder = Path(folder)
    removed = []
    if folder.is_dir():
        for f in sorted(folder.iterdir()):
            m = re.fullmatch(r"([a-z][a-z0-9_]*)-[0-9a-f]+\.txt", f.name)
            if m and m.group(1) in RULE_CONFIG_KEYS and f.name not in current:
                f.unlink(missing_ok=True)
                removed.append(f)
    return removed


def check_rule_digests(config: dict, declared: dict[str, Any]) -> None:
    """``declared``: rule name -> its ``config_digest`` param (None when it has none). Raises :class:`ConfigError`
    naming every rule without the right digest, and every map entry naming no rule."""
    problems = []
    for rule, value in sorted(declared.items()):
        if rule in RULES_WITHOUT_DIGEST:
            continue
        if rule not in RULE_CONFIG_KEYS:
            problems.append(f"rule {rule}: not in RULE_CONFIG_KEYS")
        elif value != rule_digest(config, rule):
            problems.append(f'rule {rule}: needs `params: config_digest=frng_config.rule_digest(config, "{rule}")`')
    problems += [f"RULE_CONFIG_KEYS[{r!r}]: no such rule" for r in sorted(set(RULE_CONFIG_KEYS) - set(declared))]
    if problems:
        raise ConfigError("config digests: " + "; ".join(problems))


def _schema_leaves(node: dict, prefix: str = "") -> list[str]:
    out = []
    for name, sub in (node.get("properties") or {}).items():
        if isinstance(sub, dict) and sub.get("properties"):
            out += _schema_leaves(sub, f"{prefix}{name}.")
        else:
            out.append(f"{prefix}{name}")
    return out


def undigested_keys(schema: dict | None = None) -> list[str]:
    """Config keys of the schema that no rule's digest covers (besides ``results`` and the overwrite switch): a key
    added to the schema must be added to :data:`RULE_CONFIG_KEYS` for every rule whose stage reads it."""
    schema = schema if schema is not None else load_schema()

    def within(key: str, section: str) -> bool:
        return key == section or key.startswith(section + ".")

    def covers(keys, leaf: str) -> bool:
        return any(within(leaf, k) for k in keys if not k.startswith("!")) and not any(
            within(leaf, k[1:]) for k in keys if k.startswith("!")
        )

    return [
        leaf
        for leaf in _schema_leaves(schema)
        if leaf.split(".")[0] not in _NEVER_DIGESTED
        and not any(covers(keys, leaf) for keys in RULE_CONFIG_KEYS.values())
    ]


def unknown_digest_keys(schema: dict | None = None) -> list[str]:
    """Keys of :data:`RULE_CONFIG_KEYS` that name no config key of the schema (a typo would digest as null for
    ever), plus any that must never be digested (``results``, the overwrite switch)."""
    schema = schema if schema is not None else load_schema()
    bad = []
    for rule, keys in RULE_CONFIG_KEYS.items():
        for key in keys:
            node: Any = schema
            for part in key.lstrip("!").split("."):
                node = (node or {}).get("properties", {}).get(part)
            if node is None or key.lstrip("!").split(".")[0] in _NEVER_DIGESTED:
                bad.append(f"{rule}: {key}")
    return bad


# -- the typed config -----------------------------------------------------------------------------------
#
# Stages read the validated config through one frozen :class:`Config`, built once at the stage's entry point
# (:func:`typed`): one frozen dataclass per schema section, defined beside the code that reads it and listed in
# :data:`SECTION_CLASSES`. Building a section is strict (:func:`section`): an unknown key is a ConfigError naming it,
# a missing key takes the schema's default -- config/schema.yaml is the one place defaults are written; a section
# class's fields have no defaults of their own (tests/test_config_typed.py checks both). A class may hold fields
# the schema does not have ("internal" fields: values the code sets, e.g. SaliencyConfig.top_k from frng.top_k_percent,
# the IDM trainer's fixed weight decay); those keep a Python default or are always passed, and are not part of the
# config (:func:`section_dict` leaves them out).
#
# The architecture records stored in model files (BackboneConfig, IDMConfig: a section's architecture keys plus the
# patch size and near/far, no defaults; FRNGConfig: every field set by frng.model.frng.variant_config, no defaults)
# are built with the same helper, so loading a model file whose ``config`` has a key the code does not know (or
# lacks one it needs) fails, naming it. The module settings derived from them (MaterialFormerConfig,
# FineGeometryConfig, GaussianDecodeConfig, LightIndependenceConfig) map to no section: the pipeline sets every field;
# their defaults serve direct use (tests, notebooks) only; their ``from_dict`` is strict too.
#
# The Snakemake rule files keep the validated dict, and the helpers they call while planning, which must not import
# torch, take it as well as a Config: frng.data.catalog reads its torch-free sections through :func:`config_section`,
# frng.variants reads the dict (:func:`as_dict`; its frng and idm sections live beside torch code). Config digests
# (:func:`rule_digest`) read the dict.

SECTION_CLASSES: dict[str, tuple[str, str]] = {
    "": ("frng.config", "Config"),
    "envmaps": ("frng.data.catalog", "EnvmapsConfig"),
    "envmaps.skies": ("frng.data.catalog", "SkiesConfig"),
    "envmaps.studio": ("frng.data.catalog", "StudioConfig"),
    "objects": ("frng.data.catalog", "ObjectsConfig"),
    "objects.objaverse": ("frng.data.catalog", "ObjaverseConfig"),
    "objects.libero": ("frng.data.catalog", "LiberoConfig"),
    "render": ("frng.data.catalog", "RenderConfig"),
    "backbone": ("frng.priors.backbone", "BackboneSection"),
    "backbone.train": ("frng.priors.backbone_train", "BackboneTrainConfig"),
    "idm": ("frng.priors.idm", "IDMSection"),
    "idm.train": ("frng.priors.idm_train", "IDMTrainConfig"),
    "eval": ("frng.metrics", "EvalConfig"),
    "raster": ("frng.render.raster", "RasterConfig"),
    "shading": ("frng.render.shading", "ShadingConfig"),
    "model": ("frng.nn", "ModelConfig"),
    "frng": ("frng.model.frng", "FRNGSection"),
    "frng.saliency": ("frng.model.saliency", "SaliencyConfig"),
    "train": ("frng.model.train", "TrainConfig"),
    "train.loss": ("frng.model.train", "LossConfig"),
}
"""Dotted schema key of every object-valued config section ("" = the whole config) -> (module, class) of the frozen
dataclass that holds it. Sections not listed (objects.material_mix) and list items (objects.extra, envmaps.extra)
stay plain values."""


def section_class(where: str) -> type:
    """The dataclass of the section at dotted key ``where`` (imports its module)."""
    module, name = SECTION_CLASSES[where]
    return getattr(importlib.import_module(module), name)


def _schema_node(where: str | None) -> dict:
    node = _schema()
    for part in where.split(".") if where else ():
        node = node["properties"][part]
    return node


def schema_keys(where: str) -> list[str]:
    """The keys of the schema's section at dotted key ``where`` ("" = the top level)."""
    return list(_schema_node(where).get("properties", {}))


def schema_defaults(where: str) -> dict[str, Any]:
    """The schema's defaults of the section at dotted key ``where`` (deep copies)."""
    props = _schema_node(where).get("properties", {})
    return {k: copy.deepcopy(v["default"]) for k, v in props.items() if "default" in v}


def _dotted(where: str | None, key: str) -> str:
    return f"{where}.{key}" if where else key


def _frozen_value(value: Any) -> Any:
    """Lists become tuples (a frozen section holds no list); dicts and scalars stay."""
    return tuple(_frozen_value(v) for v in value) if isinstance(value, list) else value


def section(cls: type, d: Mapping | None, where: str | None = None):
    """Build the dataclass ``cls`` from the mapping ``d`` strictly.

    ``where``: the dotted schema key the mapping is (``"train"``, ``"backbone.train"``; None for a class that maps
    to no section, e.g. a model file's architecture record). A key of ``d`` that is no field of ``cls`` raises
    :class:`ConfigError` naming it (``train.stepz: unknown key; known: ...``); a missing field takes the schema's
    default at ``where``, else its dataclass default (internal fields only), else raises naming it. A field whose
    dotted key is a section of :data:`SECTION_CLASSES` is built from its mapping the same way; lists become tuples.
    """
    d = dict(d or {})
    names = [f.name for f in dataclasses.fields(cls)]
    unknown = sorted(set(d) - set(names), key=str)
    label = where if where is not None else cls.__name__
    if unknown:
        raise ConfigError(f"{_dotted(label, str(unknown[0]))}: unknown key; known: {', '.join(sorted(names))}")
    defaults = schema_defaults(where) if where is not None else {}
    kwargs = {}
    for f in dataclasses.fields(cls):
        if f.name in d:
            value = d[f.name]
        elif f.name in defaults:
            value = defaults[f.name]
        elif f.default is not dataclasses.MISSING or f.default_factory is not dataclasses.MISSING:
            continue
        else:
            raise ConfigError(f"{_dotted(label, f.name)}: missing key")
        key = _dotted(where, f.name) if where is not None else None
        if key in SECTION_CLASSES and isinstance(value, Mapping):
            value = section(section_class(key), value, key)
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


@dataclass(frozen=True)
class Config:
    """The validated pipeline config, typed: one frozen section per top-level key (see :data:`SECTION_CLASSES`).

    Build it once per stage with :func:`typed`; ``config.train.steps``, ``config.render.resolution``, ..."""

    tier: str
    seed: int
    train_seed: int | None
    results: str
    device: str
    envmaps: EnvmapsConfig
    objects: ObjectsConfig
    render: RenderConfig
    backbone: BackboneSection
    idm: IDMSection
    eval: EvalConfig
    raster: RasterConfig
    shading: ShadingConfig
    model: ModelConfig
    frng: FRNGSection
    train: TrainConfig
    benchmarks: tuple  # imported benchmark folders (frng/benchmarks; rules/benchmarks.smk)

    @property
    def model_seed(self) -> int:
        """The learned models' seed: ``train_seed``, or the data's ``seed`` when it is null."""
        return int(self.seed if self.train_seed is None else self.train_seed)

    def to_dict(self) -> dict:
        """The config mapping again (equal to the validated dict it was built from)."""
        return section_dict(self, "")


def typed(config: Config | Mapping) -> Config:
    """The :class:`Config` of a validated config mapping (:func:`load`, :func:`validate`); a Config is returned as
    it is, so a library function may call ``typed`` on what it is given."""
    if isinstance(config, Config):
        return config
    return section(Config, config, "")


def config_section(config: Config | Mapping, key: str):
    """The top-level entry ``key`` of a :class:`Config`, or of a config mapping: a section is built from it
    (:func:`section`; the mapping may be partial: missing keys take the schema's defaults), a scalar (``seed``,
    ``results``, ...) is returned as it is. Only that section's class is imported: the planning helpers that the rule
    files call with the dict (frng.data.catalog) stay torch-free."""
    if isinstance(config, Config):
        return getattr(config, key)
    if key not in SECTION_CLASSES:
        return config[key]
    return section(section_class(key), config.get(key, {}), key)


def as_dict(config: Config | Mapping) -> Mapping:
    """The config mapping of a Config (or the mapping itself): for the helpers that the Snakemake rule files call
    with the validated dict while planning (frng.data.catalog, frng.variants)."""
    return config.to_dict() if isinstance(config, Config) else config


def add_config_argument(parser: argparse.ArgumentParser) -> None:
    """The ``--config`` option every stage shares."""
    parser.add_argument("--config", required=True, help="pipeline config YAML (validated against config/schema.yaml)")


# -- `frng config` stage -------------------------------------------------------------------------


def configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("path", help="config YAML to validate")
    parser.add_argument("--json", action="store_true", help="print the filled-in config as JSON")
    parser.add_argument("--check", action="store_true", help="validate only: print nothing when the config is valid")


def run(args: argparse.Namespace) -> int:
    try:
        config = load(args.path)
    except ConfigError as e:
        where = "" if str(e).startswith("config file") else f"{args.path}: "  # file-level errors name it already
        print(f"invalid config: {where}{e}")
        return 1
    if not args.check:
        print(json.dumps(config, indent=2) if args.json else dump(config))
    return 0


def get(config: dict, dotted: str) -> Any:
    """``get(cfg, "render.resolution")``."""
    node: Any = config
    for part in dotted.split("."):
        node = node[part]
    return node
