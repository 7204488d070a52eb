"""Files from strangers, confinement (issue 56, docs/reliability.md): every path a file names stays inside the folder
the user gave, symlinks resolved; anything else is one line naming the file and the field, unless --allow-outside.

Each probe is a case written here: crafted benchmark folders (a Stanford-ORB ``scene_name`` escaping the results
folder, NeRF-synthetic ``file_path`` with ``../``, an absolute path or a symlink out), OBJ/MTL and glTF assets naming
files outside, photo folders and the Objaverse cache holding symlinks out. Around each, a sentinel folder outside
every given folder is listed and hashed: nothing there is read into an output, written or replaced.
"""

from __future__ import annotations

import hashlib
import json
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from test_benchmarks import RES, make_curated

from frng import confine, io
from frng.benchmarks import BenchmarkError, export_object, import_scene


def snapshot(folder: Path) -> dict[str, str]:
    """Every entry under ``folder`` -> sha256 of its bytes (folders: "dir"): listing and content."""
    out = {}
    for p in sorted(Path(folder).rglob("*")):
        rel = str(p.relative_to(folder))
        out[rel] = "dir" if p.is_dir() else hashlib.sha256(p.read_bytes()).hexdigest()
    return out


def make_sentinel(root: Path) -> Path:
    """A folder of files an attacker would like read or replaced: a valid RGBA PNG, an EXR, a text file."""
    s = root / "sentinel"
    s.mkdir(parents=True)
    rgba = np.zeros((RES, RES, 4), np.float32)
    rgba[8:24, 8:24] = [0.9, 0.1, 0.1, 1.0]
    io.write_png(s / "s.png", rgba)
    io.write_exr(s / "ESCAPED.exr", rgba, channels=["R", "G", "B", "A"])
    (s / "notes.txt").write_text("private\n")
    return s


@pytest.fixture(scope="module")
def exported(tmp_path_factory):
    """A curated object exported in the NeRF-synthetic, Stanford-ORB and TensoIR layouts (the importers' input)."""
    base = tmp_path_factory.mktemp("untrusted")
    curated = base / "curated"
    make_curated(curated)
    return {
        layout: export_object(layout, curated, "obj_0000", base / layout)
        for layout in ("nerf-synthetic", "orb", "tensoir")
    }


def _copy_scene(exported, layout: str, dst: Path) -> Path:
    """A writable copy of the exported layout's whole folder (the scene with its siblings); the scene's path."""
    src = Path(exported[layout])
    top = src.parent.parent if layout == "orb" else src.parent  # orb: blender_HDR/.. holds ground_truth/ too
    shutil.copytree(top, dst)
    return dst / src.relative_to(top)


def _nothing_imported(results: Path) -> bool:
    objs, maps = results / "objects", results / "envmaps"
    return (not objs.exists() or not any(objs.iterdir())) and (not maps.exists() or not any(maps.iterdir()))


# -- case 1: an ORB scene_name escaping the results folder ---------------------------------------------------------


def test_orb_scene_name_cannot_write_outside_results(exported, tmp_path):
    sentinel = make_sentinel(tmp_path)
    scene = _copy_scene(exported, "orb", tmp_path / "orb")
    novel = scene / "transforms_novel.json"
    meta = json.loads(novel.read_text())
    results = tmp_path / "results"
    # from {results}/envmaps/{oid}_{name}.exr up to tmp_path, then into the sentinel: ESCAPED.exr would be replaced
    meta["frames"][0]["scene_name"] = "x/../../../sentinel/ESCAPED"
    novel.write_text(json.dumps(meta))
    before = snapshot(sentinel)
    with pytest.raises(BenchmarkError, match=r"transforms_novel\.json: field 'frames\[0\]\.scene_name'.*plain name"):
        import_scene("orb", scene, results, RES, 32)
    assert snapshot(sentinel) == before and _nothing_imported(results)
    assert not list(tmp_path.rglob("ESCAPED")) and not list(tmp_path.rglob("tgt_*.exr"))


def test_orb_escape_is_one_line_from_the_command(exported, tmp_path):
    from data_helpers import write_config

    sentinel = make_sentinel(tmp_path)
    scene = _copy_scene(exported, "orb", tmp_path / "orb")
    novel = scene / "transforms_novel.json"
    meta = json.loads(novel.read_text())
    meta["frames"][1]["scene_name"] = str(sentinel / "ESCAPED")
    novel.write_text(json.dumps(meta))
    before = snapshot(sentinel)
    cfg = write_config(tmp_path / "c.yaml", tmp_path / "results")
    proc = subprocess.run(
        [sys.executable, "-m", "frng", "import", "orb", str(scene), "--config", str(cfg)],
        capture_output=True,
        text=True,
        timeout=300,
    )
    lines = [ln for ln in (proc.stdout + proc.stderr).splitlines() if ln.strip()]
    assert proc.returncode == 2 and len(lines) == 1, lines
    assert "transforms_novel.json" in lines[0] and "scene_name" in lines[0], lines
    assert snapshot(sentinel) == before and _nothing_imported(tmp_path / "results")


def test_orb_image_path_out_of_its_scene(exported, tmp_path):
    sentinel = make_sentinel(tmp_path)
    scene = _copy_scene(exported, "orb", tmp_path / "orb")
    tr = scene / "transforms_train.json"
    meta = json.loads(tr.read_text())
    meta["frames"][0]["file_path"] = str(sentinel / "ESCAPED")  # an absolute path to an EXR outside
    tr.write_text(json.dumps(meta))
    with pytest.raises(BenchmarkError, match=r"transforms_train\.json: field 'frames\[0\]\.file_path'.*outside"):
        import_scene("orb", scene, tmp_path / "results", RES, 32)
    assert _nothing_imported(tmp_path / "results")


# -- case 3: NeRF-synthetic file_path out of the dataset folder ----------------------------------------------------


@pytest.mark.parametrize("how", ["dotdot", "absolute", "symlink"])
def test_nerf_synthetic_file_path_outside_is_refused(exported, tmp_path, how):
    sentinel = make_sentinel(tmp_path)
    scene = _copy_scene(exported, "nerf-synthetic", tmp_path / "ns")
    tr = scene / "transforms_train.json"
    meta = json.loads(tr.read_text())
    if how == "dotdot":
        meta["frames"][0]["file_path"] = "./" + "../" * len(scene.relative_to(tmp_path).parts) + "sentinel/s"
    elif how == "absolute":
        meta["frames"][0]["file_path"] = str(sentinel / "s")
    else:  # the file the frame names is a symlink out of the folder
        link = scene / meta["frames"][0]["file_path"].removeprefix("./")
        link.with_suffix(".png").unlink()
        link.with_suffix(".png").symlink_to(sentinel / "s.png")
    tr.write_text(json.dumps(meta))
    before = snapshot(sentinel)
    with pytest.raises(BenchmarkError) as err:
        import_scene("nerf-synthetic", scene, tmp_path / "results", RES, 32, extra_inputs=2)
    msg = str(err.value)
    assert "\n" not in msg and str(tr) in msg and "'frames[0].file_path'" in msg and "outside" in msg, msg
    assert "--allow-outside" in msg
    assert snapshot(sentinel) == before and _nothing_imported(tmp_path / "results")


def test_allow_outside_reads_it(exported, tmp_path):
    """The override: with allow_outside the absolute path is read (the input view is the sentinel's image)."""
    sentinel = tmp_path / "elsewhere"
    scene = _copy_scene(exported, "nerf-synthetic", tmp_path / "ns")
    tr = scene / "transforms_train.json"
    meta = json.loads(tr.read_text())
    first = scene / (meta["frames"][0]["file_path"].removeprefix("./") + ".png")
    sentinel.mkdir()
    shutil.copy(first, sentinel / "s.png")
    meta["frames"][0]["file_path"] = str(sentinel / "s")
    tr.write_text(json.dumps(meta))
    folder = import_scene("nerf-synthetic", scene, tmp_path / "results", RES, 32, extra_inputs=2, allow_outside=True)
    sources = io.read_json(folder / "meta.json")["benchmark"]["input_views_from"]
    assert str(sentinel / "s.png") in sources


def test_tensoir_symlinked_image_out_of_the_scene(exported, tmp_path):
    sentinel = make_sentinel(tmp_path)
    scene = _copy_scene(exported, "tensoir", tmp_path / "ti")
    png = scene / "train_002" / "rgba_sun_a.png"
    png.unlink()
    png.symlink_to(sentinel / "s.png")
    with pytest.raises(BenchmarkError, match=r"rgba_sun_a\.png.*outside.*through a symlink"):
        import_scene("tensoir", scene, tmp_path / "results", RES, 32)
    assert _nothing_imported(tmp_path / "results")


# -- names from files ---------------------------------------------------------------------------------------------


def test_names_from_files_are_sanitised_and_ids_checked():
    assert confine.safe_id("baking_scene002", source="f", field="scene_name") == "baking_scene002"
    assert confine.safe_id("x/../../ESCAPED", source="f", field="scene_name") == "x_escaped"
    assert confine.safe_id("Sky B", source="f", field="light") == "sky_b"
    with pytest.raises(confine.UntrustedInputError, match=r"f: field 'light' must be a string"):
        confine.safe_id(["a"], source="f", field="light")
    with pytest.raises(confine.UntrustedInputError, match=r"no usable characters"):
        confine.safe_id("../..", source="f", field="light")
    for bad in ("x-/../..", "../x-y", "X-Y", "a b-c", ""):
        with pytest.raises(confine.UntrustedInputError, match="no path parts"):
            confine.check_id(bad)
    for bad in ("a/b", "..", ".", "", 3, "a\\b"):
        with pytest.raises(confine.UntrustedInputError, match="plain name"):
            confine.plain_name(bad, source="t.json", field="frames[0].scene_name")


def test_import_id_with_path_parts_is_one_line(tmp_path, capsys):
    from data_helpers import write_config

    from frng import cli

    cfg = write_config(tmp_path / "c.yaml", tmp_path / "results")
    with pytest.raises(SystemExit) as ex:
        cli.main(["import", "orb", str(tmp_path), "--config", str(cfg), "--id", "x-/../.."])
    out = capsys.readouterr()
    lines = [ln for ln in (out.out + out.err).splitlines() if ln.strip()]
    assert ex.value.code == 2 and len(lines) == 1 and "x-/../.." in lines[0] and "path parts" in lines[0], lines
    assert not (tmp_path / "results").exists()


# -- own assets (OBJ/MTL, glTF) naming files outside: pure-Python checks, one Blender import -----------------------


def _box_obj(folder: Path, mtl: str | None, name: str = "box") -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    lines = [f"mtllib {name}.mtl"] if mtl is not None else []
    lines += ["v 0 0 0", "v 1 0 0", "v 0 1 0", "v 0 0 1"]
    lines += ["usemtl m"] if mtl is not None else []
    lines += ["f 1 2 3", "f 1 2 4", "f 1 3 4", "f 2 3 4"]
    (folder / f"{name}.obj").write_text("\n".join(lines) + "\n")
    if mtl is not None:
        (folder / f"{name}.mtl").write_text(mtl)
    return folder / f"{name}.obj"


@pytest.mark.parametrize(
    "mtl, field",
    [
        ("newmtl m\nmap_Kd ../sentinel/s.png\n", "map_Kd"),
        ("newmtl m\nmap_Kd -s 1 1 1 {abs}\n", "map_Kd"),
        ("newmtl m\nbump -bm 1.0 ../sentinel/s.png\n", "bump"),
    ],
)
def test_obj_texture_outside_the_asset_folder(tmp_path, mtl, field):
    sentinel = make_sentinel(tmp_path)
    obj = _box_obj(tmp_path / "asset", mtl.format(abs=sentinel / "s.png"))
    with pytest.raises(confine.OutsideError) as err:
        confine.check_mesh_references(obj)
    msg = str(err.value)
    assert msg.startswith(f"{obj.with_suffix('.mtl')}: line 2 {field}") and "outside the asset folder" in msg, msg


def test_obj_mtllib_outside_and_what_passes(tmp_path):
    sentinel = make_sentinel(tmp_path)
    (sentinel / "evil.mtl").write_text("newmtl m\nKd 1 0 0\n")
    obj = _box_obj(tmp_path / "asset", None)
    obj.write_text("mtllib ../sentinel/evil.mtl\n" + obj.read_text())
    with pytest.raises(confine.OutsideError, match=rf"{obj}: line 1 mtllib names '../sentinel/evil.mtl'"):
        confine.check_mesh_references(obj)
    # inside the folder, and a missing author path (reads nothing), pass; the override passes too
    ok = _box_obj(tmp_path / "ok", "newmtl m\nmap_Kd tex/kd.png\nmap_Ks /home/author/Downloads/ks.jpeg\n")
    confine.check_mesh_references(ok)
    confine.check_mesh_references(obj, allow_outside=True)
    # a texture inside the folder that is a symlink out
    (tmp_path / "ok" / "tex").mkdir()
    (tmp_path / "ok" / "tex" / "kd.png").symlink_to(sentinel / "s.png")
    with pytest.raises(confine.OutsideError, match=r"map_Kd names 'tex/kd.png'"):
        confine.check_mesh_references(ok)


def _gltf(path: Path, buffer_uri: str, image_uri: str | None = None, positions=None) -> Path:
    pos = np.asarray(positions if positions is not None else [[0, 0, 0], [1, 0, 0], [0, 1, 0]], "<f4")
    doc = {
        "asset": {"version": "2.0"},
        "buffers": [{"uri": buffer_uri, "byteLength": pos.nbytes}],
        "bufferViews": [{"buffer": 0, "byteOffset": 0, "byteLength": pos.nbytes}],
        "accessors": [{"bufferView": 0, "componentType": 5126, "count": len(pos), "type": "VEC3"}],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0}}]}],
        "nodes": [{"mesh": 0}],
        "scenes": [{"nodes": [0]}],
    }
    if image_uri is not None:
        doc["images"] = [{"uri": image_uri}]
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(doc))
    return pos


def test_gltf_buffer_and_image_uris_outside(tmp_path):
    sentinel = make_sentinel(tmp_path)
    pos = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], "<f4")
    (sentinel / "buf.bin").write_bytes(pos.tobytes())
    g = tmp_path / "asset" / "a.gltf"
    _gltf(g, str(sentinel / "buf.bin"))
    with pytest.raises(confine.OutsideError, match=rf"{g}: buffers\[0\]\.uri names '{sentinel / 'buf.bin'}'"):
        confine.check_mesh_references(g)
    _gltf(g, "buf.bin", image_uri="..%2Fsentinel%2Fs.png")  # URI-encoded ../
    (g.parent / "buf.bin").write_bytes(pos.tobytes())
    with pytest.raises(confine.OutsideError, match=r"images\[0\]\.uri names '../sentinel/s.png'"):
        confine.check_mesh_references(g)
    _gltf(g, "buf.bin", image_uri="data:image/png;base64,AAAA")
    confine.check_mesh_references(g)  # data URIs and files inside pass


def test_blender_import_refuses_an_outside_texture(tmp_path):
    """The check runs inside own-asset import (frng.blender.objects.import_file), before Blender opens the file."""
    pytest.importorskip("bpy")
    from frng.blender import objects

    sentinel = make_sentinel(tmp_path)
    obj = _box_obj(tmp_path / "asset", f"newmtl m\nmap_Kd {sentinel / 's.png'}\n")
    before = snapshot(sentinel)
    with pytest.raises(objects.MeshError, match=r"box\.mtl: line 2 map_Kd names .*outside the asset folder"):
        objects.import_file(obj, keep_materials=True)
    assert snapshot(sentinel) == before


# -- photos, masks, the Objaverse cache ----------------------------------------------------------------------------


def test_photo_symlinked_out_of_the_images_folder(tmp_path):
    from frng.apps.capture import CaptureError, load_images

    sentinel = make_sentinel(tmp_path)
    photos = tmp_path / "photos"
    photos.mkdir()
    shutil.copy(sentinel / "s.png", photos / "a.png")
    (photos / "b.png").symlink_to(sentinel / "s.png")
    with pytest.raises(CaptureError, match=r"b\.png.*outside.*through a symlink.*--allow-outside"):
        load_images(photos, allow_outside=False)
    assert len(load_images(photos, allow_outside=True)) == 2


def test_objaverse_glb_symlinked_out_of_the_cache(tmp_path):
    from frng.plan.dataset_config import CatalogError
    from frng.plan.object_files import _cached_glb

    sentinel = make_sentinel(tmp_path)
    uid = "0123456789abcdef0123456789abcdef"
    (tmp_path / "cache" / "glbs" / "000-000").mkdir(parents=True)
    (tmp_path / "cache" / "glbs" / "000-000" / f"{uid}.glb").symlink_to(sentinel / "notes.txt")
    with pytest.raises(CatalogError, match=rf"{uid}\.glb: resolves to .*outside the Objaverse cache"):
        _cached_glb(tmp_path / "cache", uid)
    with pytest.raises(CatalogError, match="not an Objaverse uid"):
        _cached_glb(tmp_path / "cache", "../../sentinel/notes")


def test_allow_outside_from_the_config():
    """``benchmarks[].options.allow_outside: true`` is the import's --allow-outside (rules/benchmarks.smk)."""
    from frng.benchmarks.plan import import_flags

    assert import_flags({"id": "orb-a", "options": {"allow_outside": True}}) == "--allow-outside"
    assert import_flags({"id": "orb-a", "options": {"allow_outside": False}}) == ""


def edit_orb_frames(exported, tmp_path, transforms: str, frame: int, field: str, value) -> tuple[Path, Path]:
    """A copy of the exported ORB scene with one field of one frame of ``transforms`` (e.g. "transforms_train.json")
    set to ``value``: (the scene folder, the edited file)."""
    src = exported["orb"]
    shutil.copytree(src.parent.parent, tmp_path / "orb")
    scene = tmp_path / "orb" / "blender_HDR" / src.name
    path = scene / transforms
    meta = json.loads(path.read_text())
    meta["frames"][frame][field] = value
    path.write_text(json.dumps(meta))
    return scene, path


# -- issue 87, probe 4: asset.json may point anywhere ----------------------------------------------------------------


@pytest.mark.parametrize(
    "edit, words",
    [
        (lambda m, out: m.update(ply="../outside.ply"), "field 'ply' must be a plain name"),
        (
            lambda m, out: m.update(decoder_weights=str(out / "dec.safetensors")),
            "field 'decoder_weights' must be a plain",
        ),
        (lambda m, out: m.update(ply="link.ply"), "field 'ply' names 'link.ply', which is a symlink out of"),
    ],
)
def test_asset_json_paths_stay_in_the_asset_folder(tmp_path, capsys, edit, words):
    from test_untrusted_outputs import _env, _run, tiny_asset

    asset = tiny_asset(tmp_path / "asset")
    other = tiny_asset(tmp_path / "other")  # readable files outside: the probe's render exited 0
    shutil.copy(other / "gaussians.ply", tmp_path / "outside.ply")
    shutil.copy(other / "decoder.safetensors", tmp_path / "dec.safetensors")
    (asset / "link.ply").symlink_to(tmp_path / "outside.ply")
    meta = json.loads((asset / "asset.json").read_text())
    edit(meta, tmp_path)
    (asset / "asset.json").write_text(json.dumps(meta))
    out = tmp_path / "out"
    code, lines = _run(
        ["render-asset", asset, "--env", _env(tmp_path / "e.exr"), "--out", out, "--turntable", 1], capsys
    )
    assert code == 2 and len(lines) == 1 and f"{asset / 'asset.json'}: {words}" in lines[0], lines
    assert not out.exists()


def test_asset_files_symlinked_out_are_refused(tmp_path):
    from test_untrusted_outputs import _env, tiny_asset

    from frng.apps.asset import AssetError, load_asset
    from frng.apps.view_scene import ViewError, collect_lights

    asset = tiny_asset(tmp_path / "asset")
    other = tiny_asset(tmp_path / "other")
    (asset / "gaussians.ply").unlink()
    (asset / "gaussians.ply").symlink_to(other / "gaussians.ply")
    with pytest.raises(AssetError, match=r"asset\.json: field 'ply' names 'gaussians\.ply', which is a symlink out of"):
        load_asset(asset)
    (asset / "gaussians.ply").unlink()
    shutil.copy(other / "gaussians.ply", asset / "gaussians.ply")
    load_asset(asset)  # a copy inside is fine
    (asset / "input_light.exr").symlink_to(_env(tmp_path / "light.exr"))
    with pytest.raises(ViewError, match=r"input_light\.exr: is a symlink out of the folder"):
        collect_lights(asset, None, [], None)
    inside_link = asset / "sub"
    inside_link.mkdir()
    (asset / "input_light.exr").unlink()
    _env(inside_link / "light.exr")
    (asset / "input_light.exr").symlink_to(inside_link / "light.exr")  # a link inside the folder is fine
    assert [x.label for x in collect_lights(asset, None, [], None)] == ["input light"]
