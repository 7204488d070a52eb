"""The public relighting benchmarks in the dataset contract: one module per published layout, each a reader
(``read(path, ...) -> Scene``) and a writer (``write(curated, out) -> path``) citing the benchmark's official loader
and evaluation code; :mod:`frng.benchmarks.common` converts a scene once into ``{results}/objects/{id}/`` (rig-like
input views, targets, masks, cameras, lights, world normalisation); :mod:`frng.benchmarks.protocols` holds the
published metric protocols.

=================  ==========================================  ============================  ==================
layout             module                                      what ``frng import`` reads    protocol
=================  ==========================================  ============================  ==================
``tensoir``        :mod:`frng.benchmarks.tensoir`              ``{scene}/`` (+ light_probes)  ``tensoir``
``orb``            :mod:`frng.benchmarks.orb`                  ``blender_HDR/{scene}/``       ``orb``
``owl``            :mod:`frng.benchmarks.owl`                  ``dataset/{object}/test/``     ``owl``
``nerf-synthetic`` :mod:`frng.benchmarks.nerf_synthetic`       ``{scene}/``                   ``nerf-synthetic``
=================  ==========================================  ============================  ==================
"""

from __future__ import annotations

import importlib
from pathlib import Path

from frng.benchmarks.plan import BenchmarkError, entries, object_id  # noqa: F401

LAYOUTS = {
    "tensoir": "frng.benchmarks.tensoir",
    "orb": "frng.benchmarks.orb",
    "owl": "frng.benchmarks.owl",
    "nerf-synthetic": "frng.benchmarks.nerf_synthetic",
}


def module(layout: str):
    if layout not in LAYOUTS:
        raise BenchmarkError(f"unknown benchmark layout {layout!r} (choose from {', '.join(LAYOUTS)})")
    return importlib.import_module(LAYOUTS[layout])


def import_scene(
    layout: str,
    path: str | Path,
    results: str | Path,
    resolution: int,
    envmap_width: int,
    extra_inputs: int = 0,
    max_targets: int | None = None,
    oid: str | None = None,
    **options,
) -> Path:
    """Read a benchmark folder and write it into ``{results}/objects/{id}``; returns that folder. ``options``: the
    layout's reader options (``allow_outside=True``: read files the scene's files name outside its folder)."""
    from frng.benchmarks.common import write_object
    from frng.confine import UntrustedInputError

    try:
        scene = module(layout).read(path, **{k: v for k, v in options.items() if v is not None and v is not False})
        return write_object(scene, results, resolution, envmap_width, extra_inputs, max_targets, oid)
    except UntrustedInputError as e:  # a path outside the folder, a non-finite camera, a bad name: one line
        raise BenchmarkError(str(e)) from None


def export_object(layout: str, results: str | Path, oid: str, out: str | Path, scene: str | None = None) -> Path:
    """Write curated object ``oid`` of ``results`` in ``layout``'s published layout under ``out``; returns the path
    ``frng import {layout}`` takes."""
    from frng import confine
    from frng.benchmarks.common import open_curated

    confine.check_id(oid, "object id")  # it becomes a path (the curated folder read, the scene written)
    return module(layout).write(open_curated(results, oid), out, scene)
