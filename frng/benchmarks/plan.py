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
            raise BenchmarkError(f"benchmarks[{i}] and benchmarks[{seen[e['id']]}] both import to {e['id']!r}; "
                                 f"give one an `id`")
        seen[e["id"]] = i
        out.append(e)
    return out
