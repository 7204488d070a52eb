"""Loading, validating and recording pipeline configs (``config/*.yaml`` against ``config/schema.yaml``).

One implementation serves both the workflow (``rules/common.smk`` calls :func:`validate`, :func:`record`) and the CLI
(stages call :func:`load`), so a bad config fails the same way everywhere, before any job runs, with a message naming
the offending key.

Validation is JSON Schema 2020-12 (structure, types, ranges, unknown keys) with defaults from the schema filled in,
followed by cross-key checks that a schema cannot express (see :func:`check_semantics`).

The rest of the config's machinery lives beside it, one concept a module: :mod:`frng.plan.sections` (a section's frozen
dataclass, built strictly from its mapping; a leaf), :mod:`frng.typedconfig` (the whole typed ``Config``, assembled
from the sections the components declare), :mod:`frng.plan.digests` (the config keys each rule reads) and
:mod:`frng.commands.config` (the ``frng config`` subcommand).
"""

from __future__ import annotations

import argparse
import copy
import os
import re
from pathlib import Path
from typing import Any

import yaml

from frng.plan.sections import ConfigError, load_schema


def _key(path) -> str:
    parts = [str(p) if not isinstance(p, int) else f"[{p}]" for p in path]
    return ".".join(parts).replace(".[", "[") or "<root>"


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
    check_finite(config)
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


def check_finite(config: dict) -> None:
    """One rule for every number of a config, whatever its key: NaN and inf are refused (JSON Schema's ``minimum``
    and ``maximum`` let NaN through, and YAML reads ``.nan`` / ``.inf``), naming the key."""
    from frng.confine import dotted, first_nonfinite

    bad = first_nonfinite(config)
    if bad is not None:
        value = get_path(config, bad)
        raise ConfigError(f"config key '{dotted(bad)}': {value!r} is not a finite number (NaN and inf are refused)")


def get_path(config, path: tuple):
    for p in path:
        config = config[p]
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
    unreadable, not YAML (a key given twice included: :func:`frng.confine.load_yaml`), or not a mapping at the top
    level."""
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
        from frng.confine import load_yaml

        config = load_yaml(text)  # a key given twice is refused, naming it
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


def load_overlaid(path: Path | str, *overlays: Path | str) -> dict:
    """Read a YAML config with overlay YAMLs merged over it in order (:func:`merge`, as Snakemake's ``--configfile
    PATH OVERLAY ...``; ``make seeds``: config/config.yaml + config/seeds.yaml), validate, fill defaults."""
    overrides: dict = {}
    for overlay in overlays:
        overrides = merge(overrides, read_yaml(overlay))
    return load(path, overrides)


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


def get(config: dict, dotted: str) -> Any:
    """``get(cfg, "render.resolution")``."""
    node: Any = config
    for part in dotted.split("."):
        node = node[part]
    return node


def add_config_argument(parser: argparse.ArgumentParser) -> None:
    """The ``--config`` option every stage shares."""
    parser.add_argument("--config", required=True, help="pipeline config YAML (validated against config/schema.yaml)")


def add_test_objects_argument(parser: argparse.ArgumentParser) -> None:
    """The ``--objects`` option of the stages that work on the held-out objects (:func:`heldout_objects` reads it)."""
    parser.add_argument("--objects", nargs="*", help="test objects (default: the config's test split)")


def heldout_objects(config, objects: list[str] | None) -> list[str]:
    """``--objects`` as given, else the config's test split (:func:`frng.plan.catalog.plan`)."""
    from frng.plan import catalog

    return list(objects) if objects else catalog.plan(config).split("test")
