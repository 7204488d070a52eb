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
import json
from pathlib import Path
from typing import Any

import yaml

SCHEMA_PATH = Path(__file__).resolve().parent.parent / "config" / "schema.yaml"


class ConfigError(ValueError):
    """A config value is invalid. The message starts with the dotted key path."""


def _key(path) -> str:
    parts = [str(p) if not isinstance(p, int) else f"[{p}]" for p in path]
    return ".".join(parts).replace(".[", "[") or "<root>"


def load_schema(path: Path | str = SCHEMA_PATH) -> dict:
    with open(path) as f:
        return yaml.safe_load(f)


def _validator_with_defaults(schema: dict):
    from jsonschema import Draft202012Validator, validators

    base = Draft202012Validator

    def set_defaults(validator, properties, instance, schema_):
        if isinstance(instance, dict):
            for name, sub in properties.items():
                if "default" in sub and name not in instance:
                    instance[name] = copy.deepcopy(sub["default"])
        yield from base.VALIDATORS["properties"](validator, properties, instance, schema_)

    cls = validators.extend(base, {"properties": set_defaults})
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
        raise ConfigError(
            f"config key 'render.resolution': {res} is not a multiple of model.patch_size ({patch})"
        )
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


def load(path: Path | str, overrides: dict | None = None) -> dict:
    """Read a YAML config, apply ``overrides`` (nested dict, merged), validate, fill defaults."""
    path = Path(path)
    if not path.exists():
        raise ConfigError(f"config file {path} does not exist")
    with open(path) as f:
        config = yaml.safe_load(f) or {}
    if not isinstance(config, dict):
        raise ConfigError(f"config file {path}: top level must be a mapping")
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


def write_resolved(config: dict, path: Path | str) -> None:
    """Write a validated config as YAML, only if the content differs (keeps mtimes stable)."""
    path = Path(path)
    text = yaml.safe_dump(config, sort_keys=False)
    if path.exists() and path.read_text() == text:
        return
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".tmp-{path.name}")
    tmp.write_text(text)
    tmp.replace(path)


def add_config_argument(parser: argparse.ArgumentParser) -> None:
    """The ``--config`` option every stage shares."""
    parser.add_argument("--config", required=True, help="pipeline config YAML (validated against config/schema.yaml)")


# -- `frng config` stage -------------------------------------------------------------------------

def configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("path", help="config YAML to validate")
    parser.add_argument("--json", action="store_true", help="print the filled-in config as JSON")


def run(args: argparse.Namespace) -> int:
    try:
        config = load(args.path)
    except ConfigError as e:
        print(f"invalid config {args.path}: {e}")
        return 1
    print(json.dumps(config, indent=2) if args.json else yaml.safe_dump(config, sort_keys=False))
    return 0


def get(config: dict, dotted: str) -> Any:
    """``get(cfg, "render.resolution")``."""
    node: Any = config
    for part in dotted.split("."):
        node = node[part]
    return node
