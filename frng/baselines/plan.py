"""Planning of the baselines (torch-free: the rule files import it): the ``baselines`` config section, the test
objects the per-scene baselines run on, the dense views on a sphere and their spread subsets, the run names.

Run names (folders under ``{results}/relight/``, :class:`frng.plan.layout.RelightFolder`):

- ``{method}-v{n}``: per-scene ``method`` (:mod:`frng.baselines.registry`: ``3dgs``, ``gsir``) fitted on ``n`` of
  the object's dense views (:func:`dense_subset`); relit under every target light (a method that relights: ``gsir``)
  and re-rendered under the input light at the target views (novel-view synthesis, every method);
- ``idm-reshade``: the image-based baseline;
- ``ext-{name}``: another method's outputs read from files (``baselines.external``).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from frng.baselines import registry
from frng.baselines.fit_settings import FitSettings
from frng.data.rig import View, make_view
from frng.plan.sections import key, register

IMAGE_BASED_RUN = "idm-reshade"
FRNG_RUN = "full"  # the F-RNG run the baselines are compared with (rule relight)
FRNG_NVS_RUN = "full-nvs"  # its novel views under the input light (rule baseline_frng_nvs)
DENSE_KIND = "dense"  # ObjectFolder.image kind of the dense views
TARGETS_KIND = "targets"  # ... and of the target views under the input light (the image-based methods' input)


@register("baselines")
@dataclass(frozen=True)
class BaselinesConfig:
    """The config's ``baselines`` section (each key declared on its field)."""

    CONFIG_DOC = (
        "the comparisons of the paper's Tables 2-3 and its views table (frng/baselines): per-scene models fitted on "
        "dense views, image-based relighting, and other methods' outputs read from files"
    )

    objects_per_class: int | None = key(
        None,
        "test objects per material class the per-scene baselines run on (the first of each class in the test split's "
        "order); null: every test object",
        type=["integer", "null"],
        minimum=1,
        maximum=100000,
    )
    view_counts: tuple[int, ...] = key(
        [6],
        "input-view counts the per-scene baselines are fitted with (nested spread subsets of the dense views); the "
        "largest is Table 2's dense setting, all of them the views table's columns",
        type="array",
        items={"type": "integer", "minimum": 1, "maximum": 1000},
    )
    methods: tuple[str, ...] = key(
        list(registry.names()),
        "per-scene baselines trained here, by name in frng/baselines/registry.py: `3dgs` (plain splatting, novel "
        "views only), `gsir` (GS-IR-style relightable)",
        type="array",
        items={"type": "string"},
    )
    image_based: bool = key(
        True,
        "the image-based baseline: each target view's photo under the input light decomposed by the IDM and re-shaded",
        type="boolean",
    )
    external: tuple = key(
        [],
        "other methods' outputs read from files: items `{name, path, encoding: srgb|linear, family: dense|image}`, "
        "layout `{path}/{obj}/{light}/{view}.{png,exr}`",
        type="array",
        items={
            "type": "object",
            "additionalProperties": False,
            "required": ["name", "path"],
            "properties": {
                "name": {"type": "string", "pattern": "^[a-z0-9_]+$"},
                "path": {"type": "string"},
                "encoding": {"type": "string", "enum": ["srgb", "linear"], "default": "srgb"},
                "family": {"type": "string", "enum": ["dense", "image"], "default": "image"},
            },
        },
    )
    fit: FitSettings = key({})


def per_scene_run(method: str, views: int) -> str:
    """The run name of per-scene ``method`` fitted on ``views`` dense views."""
    registry.method(method)
    return f"{method}-v{int(views)}"


def external_run(name: str) -> str:
    return f"ext-{name}"


def _section(config: Mapping) -> Mapping:
    return config.get("baselines") or {}


def baseline_objects(config: Mapping, test_objects: list[tuple[str, str]]) -> list[str]:
    """The test objects the per-scene baselines run on: the first ``baselines.objects_per_class`` of each material
    class in the test split's order (``test_objects``: (id, class) pairs, class from the plan: diffuse / specular /
    fur / own), in that order; every test object when it is null. None when ``render.dense_views`` is 0."""
    if int(config["render"].get("dense_views", 0) or 0) == 0:
        return []
    per_class = _section(config).get("objects_per_class")
    if per_class is None:
        return [oid for oid, _ in test_objects]
    taken: dict[str, int] = {}
    out = []
    for oid, cls in test_objects:
        if taken.get(cls, 0) < int(per_class):
            taken[cls] = taken.get(cls, 0) + 1
            out.append(oid)
    return out


def test_objects(catalog) -> list[tuple[str, str]]:
    """(id, planned material class) of the test split of a dataset plan (:func:`frng.plan.catalog.plan`), in its
    order: what :func:`baseline_objects` picks from."""
    return [(o.id, o.material) for o in catalog.objects if o.split == "test"]


def per_scene_methods(config: Mapping) -> list[registry.PerSceneMethod]:
    """The specs of the per-scene methods the config asks for (``baselines.methods``, checked against
    :mod:`frng.baselines.registry` here, once: a one-line ValueError naming the key); none without dense views."""
    if int(config["render"].get("dense_views", 0) or 0) == 0:
        return []
    return [registry.method(m) for m in _section(config).get("methods", registry.names())]


def view_counts(config: Mapping) -> list[int]:
    """``baselines.view_counts``: the dense-view counts each per-scene method is fitted with."""
    return [int(n) for n in _section(config).get("view_counts", [6])]


def per_scene_runs(config: Mapping) -> list[str]:
    """Every per-scene run name the config asks for (methods x view counts); none without dense views."""
    return [per_scene_run(m.name, n) for m in per_scene_methods(config) for n in view_counts(config)]


def check_view_counts(config: Mapping) -> None:
    """Each ``baselines.view_counts`` entry fits in ``render.dense_views`` (a one-line ValueError naming the key)."""
    dense = int(config["render"].get("dense_views", 0) or 0)
    if dense == 0:
        return
    for n in view_counts(config):
        if n > dense:
            raise ValueError(f"baselines.view_counts: {n} views asked, render.dense_views is {dense}")


def dense_views(count: int, distance: float, fov_deg: float, resolution: int) -> list[View]:
    """``count`` views on a Fibonacci lattice of the sphere (names ``d000 ..``, kind ``dense``), all looking at the
    origin from ``distance``: the dense capture of the per-scene methods (GS-IR / R3DG / TensoIR use 100 views on a
    (hemi)sphere). Deterministic: no seed. The lattice's poles are avoided (z in (-1, 1) at half steps), so no
    camera looks straight along the up axis."""
    golden = math.pi * (3.0 - math.sqrt(5.0))
    views = []
    for i in range(int(count)):
        z = 1.0 - (2.0 * i + 1.0) / count
        az = math.degrees((i * golden) % (2.0 * math.pi))
        el = math.degrees(math.asin(z))
        views.append(make_view(f"d{i:03d}", DENSE_KIND, az, el, distance, fov_deg, resolution))
    return views


def dense_subset(views: list[View], n: int) -> list[View]:
    """The first ``n`` views of a farthest-point order of ``views`` (camera centres) starting from the first: spread
    subsets, nested (the 6 views are among the 12, which are among the 24 ...), the same for every method."""
    if not 1 <= n <= len(views):
        raise ValueError(f"dense_subset: {n} views asked of {len(views)}")
    centres = np.array([np.asarray(v.c2w, dtype=np.float64)[:3, 3] for v in views])
    order = [0]
    dist = np.linalg.norm(centres - centres[0], axis=1)
    while len(order) < n:
        nxt = int(np.argmax(dist))
        order.append(nxt)
        dist = np.minimum(dist, np.linalg.norm(centres - centres[nxt], axis=1))
    return [views[i] for i in order]
