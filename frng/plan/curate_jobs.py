"""What the workflow needs of the dataset plan for one curation job (rules/curate.smk, rules/common.smk): its runtime
estimate (:func:`curate_minutes`), its record file, named by the digest of the object's plan entry and its maps'
records (:func:`curate_record`, :func:`curate_digest`, :func:`write_curate_record`; rule ``curate_record``), and its
input files (:func:`curate_inputs`). The plan itself: :mod:`frng.plan.catalog`."""

from __future__ import annotations

import hashlib
import json
import os
import re
from collections.abc import Mapping
from pathlib import Path

from frng import io
from frng.plan.catalog import Catalog, EnvMapSpec, ObjectSpec, plan
from frng.plan.dataset_config import CatalogError
from frng.plan.layout import Layout
from frng.plan.sections import TypedConfig, config_section


def images_per_object(config: TypedConfig | Mapping, spec: ObjectSpec) -> int:
    """Number of RGBA images one curation job renders."""
    r = config_section(config, "render")
    return (r.input_views + r.extra_input_views) * len(spec.input_lights) + r.target_views * len(spec.target_lights)


def curate_minutes(config: TypedConfig | Mapping, spec: ObjectSpec) -> int:
    """Runtime estimate of one curation job in minutes: ~0.1 s per 64 px / 32 spp image on 2 threads
    (measured), scaled by pixels x samples / threads, times 3 for margin, plus 5 min start-up slack."""
    r = config_section(config, "render")
    per_image = 0.1 * (r.resolution / 64) ** 2 * (r.spp / 32) * 2 / r.threads
    return max(5, int(3 * images_per_object(config, spec) * per_image / 60) + 5)


def object_envmaps(catalog: Catalog, spec: ObjectSpec) -> list[EnvMapSpec]:
    """The planned maps of object ``spec``'s light draws, input lights first, each once."""
    return [catalog.envmap(name) for name in dict.fromkeys(spec.input_lights + spec.target_lights)]


def curate_record(catalog: Catalog, spec: ObjectSpec) -> dict:
    """What object ``spec``'s curation renders besides the render settings (its rule's digest): its plan entry and
    the plan's record of each of its maps (base, source, rotation, sky / studio parameters, file). With
    ``envmaps.width`` and ``envmaps.normalize`` (the curate rule's digest) and the user's map files
    (:func:`curate_inputs`) this decides every pixel of the object's maps."""
    return {"object": spec.to_dict(), "lights": [e.to_dict() for e in object_envmaps(catalog, spec)]}


def curate_digest(catalog: Catalog, spec: ObjectSpec) -> str:
    """16 hex digits of sha256 over :func:`curate_record` (canonical JSON): names the object's record file
    (:meth:`frng.plan.layout.Layout.curate_record`), so a changed record names another file and reruns the job."""
    cache = catalog.__dict__.get("_curate_digests")
    if cache is None:
        cache = {}
        object.__setattr__(catalog, "_curate_digests", cache)  # (planned once per object: targets and inputs)
    if spec.id not in cache:
        text = json.dumps(curate_record(catalog, spec), sort_keys=True, separators=(",", ":"), default=str)
        cache[spec.id] = hashlib.sha256(text.encode()).hexdigest()[:16]
    return cache[spec.id]


def write_curate_record(catalog: Catalog, spec: ObjectSpec, path: str | os.PathLike) -> Path:
    """Write ``path`` (``.digests/objects/{obj}-{digest}.json``, the rule ``curate_record``) and remove the object's
    other record files, so that going back to an earlier plan finds its file missing again (and reruns the job)."""
    path = Path(path)
    digest = curate_digest(catalog, spec)
    if path.name != f"{spec.id}-{digest}.json":
        raise CatalogError(f"{path}: not the curation record of {spec.id} for this plan ({spec.id}-{digest}.json)")
    io.write_json(path, {"digest": digest, **curate_record(catalog, spec)})
    for other in path.parent.glob(f"{spec.id}-*.json"):
        if other != path and re.fullmatch(rf"{re.escape(spec.id)}-[0-9a-f]+\.json", other.name):
            other.unlink(missing_ok=True)
    return path


def curate_inputs(config: TypedConfig | Mapping, spec: ObjectSpec) -> dict:
    """Input files of one curation job: the env-map index (the rule marks it ``ancient``: it orders the job after
    ``frng envmaps``, but its rewrite -- whenever any object's maps change, e.g. an object added -- reruns no
    curation; listing every light map instead would give the paper-scale DAG 100k inputs and minutes of planning),
    the object's record file (what its maps are, named by their digest: :func:`curate_record`), the user's map
    files its lights are drawn from and a user's mesh."""
    layout, catalog = Layout(config_section(config, "results")), plan(config)
    inputs: dict = {
        "index": layout.envmap_index(),
        "record": layout.curate_record(spec.id, curate_digest(catalog, spec)),
    }
    user_maps = sorted({e.origin for e in object_envmaps(catalog, spec) if e.source == "user"})
    if user_maps:
        inputs["user_envmaps"] = user_maps
    if spec.source == "user":
        inputs["mesh"] = spec.mesh
    return inputs
