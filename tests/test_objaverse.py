"""Objaverse, the paper's own object source (objects.objaverse; issue 23 item 3).

The tests write GLBs (and annotations) into the objaverse package's cache layout themselves
(``{cache}/glbs/{group}/{uid}.glb``, ``{cache}/metadata/{group}.json.gz``); nothing is downloaded. A stub
``objaverse`` module stands in for the package where its download path is exercised."""

import gzip
import json
import subprocess
import sys
import types

import pytest
import yaml
from asset_writers import halves, write_glb
from conftest import ROOT, venv_bin
from data_helpers import frng, write_config

from frng.data.dataset import open_object
from frng.plan import catalog, dataset_config
from frng.plan import config as frng_config

UIDS = ["0123456789abcdef0123456789abcdef", "fedcba9876543210fedcba9876543210", "00000000000000000000000000000abc"]


def _glb(cache, uid, group="000-000"):
    return write_glb(
        cache / "glbs" / group / f"{uid}.glb",
        {
            "name": "painted",
            "pbrMetallicRoughness": {
                "baseColorTexture": {"index": "bc"},
                "metallicFactor": 0.0,
                "roughnessFactor": 0.7,
            },
        },
        {"bc": halves((200, 60, 40), (40, 60, 200))},
    )


def _annotations(cache, group="000-000", **ann):
    (cache / "metadata").mkdir(parents=True, exist_ok=True)
    with gzip.open(cache / "metadata" / f"{group}.json.gz", "wt") as fh:
        json.dump(ann, fh)


def _cfg(cache, **objaverse):
    return frng_config.validate(
        {
            "tier": "custom",
            "objects": {
                "count": 2,
                "test_count": 1,
                "sources": ["primitives"],
                "objaverse": {"cache": str(cache), **objaverse},
            },
            "envmaps": {"bundled": ["city", "studio", "forest"], "skies": {"models": []}, "rotations": 1},
            "render": {"resolution": 32, "input_lights": 1, "target_lights": 1},
        }
    )


def test_plan_lists_uids_offline(tmp_path):
    cfg = _cfg(tmp_path / "nothing_here", uids=UIDS, test_count=1)
    objs = [o for o in catalog.plan(cfg).objects if o.source == "objaverse"]
    assert [o.id for o in objs] == [f"objaverse_{u}" for u in UIDS]
    assert sorted(o.split for o in objs) == ["test", "train", "train"]
    assert all(o.material == "own" and o.up == "y" and o.mesh in UIDS for o in objs)
    with pytest.raises(frng_config.ConfigError, match="objaverse.uids"):
        _cfg(tmp_path, uids=["not-a-uid"])
    # the default adds nothing, and the other objects' specs are unchanged
    base = frng_config.validate(
        {
            "tier": "custom",
            "objects": {"count": 2, "test_count": 1, "sources": ["primitives"]},
            "envmaps": {"bundled": ["city", "studio", "forest"], "skies": {"models": []}, "rotations": 1},
            "render": {"resolution": 32, "input_lights": 1, "target_lights": 1},
        }
    )
    assert [o.to_dict() for o in catalog.plan(base).objects] == [
        o.to_dict() for o in catalog.plan(cfg).objects if o.source != "objaverse"
    ]


def test_cache_is_read_and_missing_uids_are_named(tmp_path, monkeypatch):
    cache = tmp_path / "cache"
    path = _glb(cache, UIDS[0], "000-017")
    cfg = _cfg(cache, uids=UIDS[:2], download=False)
    stub = types.ModuleType("objaverse")
    stub.load_objects = lambda uids, **kw: pytest.fail("nothing may be fetched when the files are there")
    monkeypatch.setitem(sys.modules, "objaverse", stub)
    assert catalog.objaverse_file(cfg, UIDS[0]) == path
    with pytest.raises(dataset_config.CatalogError) as e:
        catalog.objaverse_file(cfg, UIDS[1])
    msg = str(e.value)
    assert "\n" not in msg and UIDS[1] in msg and UIDS[0] not in msg and str(cache) in msg


def test_missing_uids_are_fetched_by_the_package(tmp_path, monkeypatch):
    cache = tmp_path / "cache"
    cfg = _cfg(cache, uids=UIDS[:2])
    calls = []
    stub = types.ModuleType("objaverse")
    stub._VERSIONED_PATH = "~/.objaverse/hf-objaverse-v1"

    def load_objects(uids, download_processes=1):
        from pathlib import Path

        calls.append((stub._VERSIONED_PATH, list(uids)))
        return {u: str(_glb(Path(stub._VERSIONED_PATH), u, "000-001")) for u in uids}

    stub.load_objects = load_objects
    monkeypatch.setitem(sys.modules, "objaverse", stub)
    got = catalog.objaverse_file(cfg, UIDS[1])
    assert got == cache / "glbs" / "000-001" / f"{UIDS[1]}.glb" and got.is_file()
    assert calls == [(str(cache), UIDS[:2])]  # every missing uid of the plan in one call, into the configured cache
    catalog.objaverse_file(cfg, UIDS[0])
    assert len(calls) == 1


def test_annotation_filter_and_count(tmp_path, monkeypatch):
    cache = tmp_path / "cache"
    _annotations(
        cache,
        **{
            UIDS[0]: {"name": "chair", "license": "by", "tags": [{"name": "chair"}], "faceCount": 100},
            UIDS[1]: {"name": "big chair", "license": "by", "tags": [{"name": "chair"}], "faceCount": 10**6},
            UIDS[2]: {"name": "car", "license": "cc0", "tags": [{"name": "car"}], "faceCount": 50},
        },
    )
    cfg = _cfg(cache, filter={"tags": ["chair", "car"], "max_faces": 1000}, count=2)
    assert sorted(o.mesh for o in catalog.plan(cfg).objects if o.source == "objaverse") == sorted([UIDS[0], UIDS[2]])
    ov = catalog.config_section(cfg, "objects").objaverse
    assert len(list((cache / "frng-selections").glob("*.json"))) == 1  # the draw is remembered ...
    monkeypatch.setattr(catalog, "objaverse_annotations", lambda *a: pytest.fail("annotations re-read"))
    assert sorted(catalog.objaverse_select(ov, 0)) == sorted([UIDS[0], UIDS[2]])  # ... and re-used
    monkeypatch.undo()
    cfg = _cfg(cache, filter={"licenses": ["cc0"]}, count=2)
    with pytest.raises(dataset_config.CatalogError, match="objaverse.count"):
        catalog.plan(cfg)


@pytest.mark.blender
def test_objaverse_object_is_curated_from_the_cache(tmp_path):
    cache = tmp_path / "cache"
    _glb(cache, UIDS[0])
    _annotations(
        cache,
        **{
            UIDS[0]: {"name": "painted box", "license": "by", "viewerUrl": f"https://sketchfab.com/3d-models/{UIDS[0]}"}
        },
    )
    cfg = write_config(
        tmp_path / "config.yaml",
        tmp_path / "results",
        objects={
            "count": 2,
            "test_count": 1,
            "sources": ["primitives"],
            "objaverse": {"uids": UIDS[:2], "cache": str(cache), "download": False},
        },
        render={"resolution": 32, "spp": 2, "target_views": 1},
    )
    frng("envmaps", "--config", str(cfg))
    frng("curate", "--config", str(cfg), "--object", f"objaverse_{UIDS[0]}")
    meta = open_object(tmp_path / "results", f"objaverse_{UIDS[0]}").meta
    assert meta["source"] == "objaverse" and meta["material"]["class"] == "own"
    assert meta["licence"].startswith("by ") and meta["objaverse"]["name"] == "painted box"
    bad = frng("curate", "--config", str(cfg), "--object", f"objaverse_{UIDS[1]}", check=False)
    assert bad.returncode != 0 and UIDS[1] in bad.stderr + bad.stdout


def test_dry_run_with_objaverse_uids_is_offline(tmp_path):
    cfg = yaml.safe_load((ROOT / "config" / "smoke.yaml").read_text())
    cfg["objects"]["objaverse"] = {"uids": UIDS[:2], "test_count": 1, "cache": str(tmp_path / "empty")}
    path = tmp_path / "config.yaml"
    path.write_text(yaml.safe_dump(cfg))
    proc = subprocess.run(
        [
            venv_bin("snakemake"),
            "--snakefile",
            "workflow/Snakefile",
            "--configfile",
            str(path),
            "--config",
            f"results={tmp_path / 'results'}",
            "-n",
            "--quiet",
            "rules",
        ],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert not (tmp_path / "empty").exists()
    counts = {
        l.split()[0]: int(l.split()[1])
        for l in (proc.stdout + proc.stderr).splitlines()
        if len(l.split()) == 2 and l.split()[1].isdigit()
    }
    assert counts["curate"] == cfg["objects"]["count"] + 2
