"""Torch-free planning helpers for the workflow (rules/benchmarks.smk imports this while planning): the object id
each ``benchmarks:`` entry of the config imports to, and the error type every importer raises."""

from __future__ import annotations

import re
from pathlib import Path


class BenchmarkError(ValueError):
    """A benchmark folder is missing a file, has the wrong layout or inconsistent content; names the file."""


def object_id(layout: str, scene: str) -> str:
    """``{layout}-{scene}`` lower-cased, [a-z0-9_-]: the hyphen keeps imported ids apart from curated ones
    (``[a-z0-9_]+``), so the workflow's curate/relight rules never claim them."""
    return f"{layout}-" + (re.sub(r"[^a-z0-9_]+", "_", scene.lower()).strip("_") or "scene")


def scene_name(layout: str, path: str | Path) -> str:
    """The benchmark's scene name from the folder ``frng import`` reads (OWL: ``dataset/{object}/test`` -> object)."""
    p = Path(path)
    if layout == "owl" and p.name == "test":
        return p.parent.name
    return p.name


def entries(config) -> list[dict]:
    """The config's ``benchmarks:`` entries with their ``id`` filled in; two entries with one id is an error."""
    raw = config["benchmarks"] if isinstance(config, dict) else config.benchmarks
    out, seen = [], {}
    for i, e in enumerate(raw or []):
        e = dict(e)
        e["id"] = e.get("id") or object_id(e["layout"], scene_name(e["layout"], e["path"]))
        if e["id"] in seen:
            raise BenchmarkError(
                f"benchmarks[{i}] and benchmarks[{seen[e['id']]}] both import to {e['id']!r}; give one an `id`"
            )
        seen[e["id"]] = i
        out.append(e)
    return out


IMPORT_OPTIONS = {
    "envmaps": "--envmaps",
    "input_light": "--input-light",
    "lights": "--lights",
    "ground_truth": "--ground-truth",
    "envmap_file": "--envmap",
    "allow_outside": "--allow-outside",
}
"""``benchmarks[].options`` key -> its ``frng import`` flag."""


def import_flags(entry: dict) -> str:
    """The ``frng import`` flags of one ``benchmarks:`` entry (``max_targets``, ``options``), shell-quoted."""
    import shlex

    flags = [f"--max-targets {int(entry['max_targets'])}"] if entry.get("max_targets") else []
    for key, value in (entry.get("options") or {}).items():
        if key not in IMPORT_OPTIONS:
            raise BenchmarkError(f"benchmarks: {entry['id']}: unknown option {key!r} ({', '.join(IMPORT_OPTIONS)})")
        if key == "allow_outside":  # a switch: present when true
            flags += [IMPORT_OPTIONS[key]] if value is True else []
            continue
        values = value if isinstance(value, list) else [value]
        flags.append(IMPORT_OPTIONS[key] + " " + " ".join(shlex.quote(str(v)) for v in values))
    return " ".join(flags)
