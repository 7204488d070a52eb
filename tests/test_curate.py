"""A real (tiny) curation of one object: files, sizes, alpha, G-buffer channels, camera conventions,
and bad inputs that must fail loudly and leave nothing behind."""

import shutil

import numpy as np
import pytest
import torch
from data_helpers import frng, write_config

from frng import camera, io
from frng.data.curate import GBUFFER_CHANNELS
from frng.data.dataset import open_object

pytestmark = pytest.mark.blender
RES = 64  # pixel footprint at the object ~0.038 world units (distance 2.6, fov 50)
PIXEL = 2 * 2.6 * np.tan(np.radians(25)) / RES


@pytest.fixture(scope="module")
def curated(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("curate")
    cfg = write_config(tmp / "config.yaml", tmp / "results", render={"resolution": RES})
    frng("envmaps", "--config", str(cfg))
    proc = frng("curate", "--config", str(cfg), "--object", "obj_0000")
    return tmp, cfg, proc


def test_files_sizes_alpha_and_log(curated):
    tmp, _, proc = curated
    obj = open_object(tmp / "results", "obj_0000")
    out = proc.stdout.replace(str(tmp), "<tmp>")  # pytest's folder (e.g. pytest-112/) is not a progress bar
    assert "render" in out and "12/" not in out  # per-image progress lines with times
    assert proc.stdout.count(" render ") == 6 + 2
    assert obj.view_names("inputs") == [f"in_{i:02d}" for i in range(6)]
    for kind, lights in (("inputs", obj.input_lights), ("targets", obj.target_lights)):
        for light in lights:
            imgs = obj.images(kind, light)
            assert imgs.shape[1:] == (RES, RES, 4) and imgs.dtype == np.float32
            cover = imgs[..., 3].mean(axis=(1, 2))
            assert np.all(cover > 0.05) and np.all(cover < 0.9), cover
            assert np.all(imgs[..., 3] <= 1.0 + 1e-5) and np.isfinite(imgs).all()
    assert not list((tmp / "results" / "objects").glob(".tmp-*"))
    meta = obj.meta
    assert meta["licence"] and meta["material_class"] in ("diffuse", "specular", "fur") and meta["seed"] >= 0
    assert set(meta["render_seconds"]) == set(obj.input_lights) | set(obj.target_lights)


def test_curation_runs_without_importing_torch(curated, tmp_path):
    """A curation job imports no torch (~2.5 s of each of the ~140 jobs of a default-tier run): frng.lazytorch."""
    import subprocess
    import sys

    _, cfg, _ = curated
    cmd = [sys.executable, "-X", "importtime", "-m", "frng", "curate", "--config", str(cfg), "--object", "obj_0000"]
    proc = subprocess.run(cmd + ["--out", str(tmp_path / "objects")], capture_output=True, text=True)
    assert proc.returncode == 0, proc.stdout[-2000:]
    imported = {ln.rsplit("|", 1)[-1].strip() for ln in proc.stderr.splitlines() if ln.startswith("import time:")}
    assert "bpy" in imported and "torch" not in imported


def test_gbuffer_channels(curated):
    tmp, _, _ = curated
    obj = open_object(tmp / "results", "obj_0000")
    ch = io.read_exr_channels(obj.root / "gbuffer" / "in_00.exr")
    assert sorted(ch) == sorted(GBUFFER_CHANNELS)
    gb = obj.gbuffer("inputs")
    a = gb["alpha"][..., 0]
    inside = a > 0.99
    n = np.linalg.norm(gb["normal"], axis=-1)
    assert np.allclose(n[inside], 1.0, atol=1e-3)
    assert np.all(gb["depth"][..., 0][inside] > 0.5) and np.all(gb["depth"][..., 0][a == 0] == 0)
    for key in ("roughness", "metallic"):
        assert gb[key].min() >= 0 and gb[key].max() <= 1
    assert gb["albedo"][inside].max() > 0


def _unproject(depth, c2w, K):
    """Pixels with depth -> world points (N, 3) (OpenCV: depth is camera z)."""
    rows, cols = np.nonzero(depth > 0)
    z = depth[rows, cols]
    x = (cols + 0.5 - K[2]) / K[0] * z
    y = (rows + 0.5 - K[3]) / K[1] * z
    pc = np.stack([x, y, z, np.ones_like(z)], -1)
    return (pc @ c2w.T)[:, :3]


def test_camera_conventions_reproject_between_views(curated):
    """Surface points seen (via depth) in one view land inside the object's silhouette in other views, and
    agree with those views' depth where visible: meta.json cameras are where Blender rendered from."""
    tmp, _, _ = curated
    obj = open_object(tmp / "results", "obj_0000")
    c2w, K = obj.cameras("inputs")
    gb = obj.gbuffer("inputs")
    depth, alpha = gb["depth"][..., 0], gb["alpha"][..., 0]
    for a, b in ((0, 4), (1, 4), (2, 5), (3, 5)):  # 45 deg apart: large shared visible surface
        pts = _unproject(np.where(alpha[a] > 0.99, depth[a], 0), c2w[a].astype(np.float64), K[a])
        radius = np.linalg.norm(pts, axis=1)
        assert radius.max() < 1.03 and radius.max() > 0.7  # the object is normalised into the unit sphere
        uv, z = camera.project(
            torch.tensor(pts), torch.tensor(c2w[b : b + 1]).double(), torch.tensor(K[b : b + 1]).double()
        )
        uv, z = uv[0].numpy(), z[0].numpy()
        col, row = np.floor(uv[:, 0]).astype(int), np.floor(uv[:, 1]).astype(int)
        ok = (col >= 0) & (col < RES) & (row >= 0) & (row < RES)
        assert ok.mean() > 0.99
        col, row, z = col[ok], row[ok], z[ok]
        # depth comes from one sample (anywhere in a ~1.5 px filter footprint): allow 1 px at the edges
        sil = alpha[b] > 0
        sil = sil | np.roll(sil, 1, 0) | np.roll(sil, -1, 0) | np.roll(sil, 1, 1) | np.roll(sil, -1, 1)
        assert sil[row, col].mean() > 0.98, f"views {a}->{b}: only {sil[row, col].mean():.2f} inside the silhouette"
        r = depth[b][row, col] - z  # > 0: the point would float in front of what view b sees (impossible)
        assert (r < 2 * PIXEL).mean() > 0.9, (
            f"views {a}->{b}: {(r >= 2 * PIXEL).mean():.2f} of the points float in front"
        )
        assert (np.abs(r) < PIXEL).mean() > 0.05, f"views {a}->{b}: no shared visible surface"


def test_corrupt_envmap_fails_naming_file_and_leaves_nothing(curated, tmp_path):
    tmp, cfg, _ = curated
    env = tmp_path / "envmaps"
    shutil.copytree(tmp / "results" / "envmaps", env)
    obj = open_object(tmp / "results", "obj_0000")
    bad = env / f"{obj.input_lights[0]}.exr"
    bad.write_bytes(b"not an exr at all")
    out = tmp_path / "objects"
    proc = frng(
        "curate", "--config", str(cfg), "--object", "obj_0000", "--envmaps", str(env), "--out", str(out), check=False
    )
    assert proc.returncode != 0
    assert str(bad) in proc.stderr and "obj_0000" in proc.stderr
    assert not out.exists() or not any(out.iterdir())


@pytest.mark.parametrize(
    "mesh_text, expect",
    [
        ("v 0 0 0\nv 1 0 0\nv 1 0.0000001 0\nf 1 2 3\n", "rendered empty"),  # a sliver: loads, renders nothing
        ("this is not an obj file\n", "no mesh with faces"),
        ("v 0 0 0\nv 1 0 0\nv nan 1 0\nv 0 0 1\nf 1 2 3\nf 1 2 4\n", "non-finite vertex coordinate"),  # NaN
        ("v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 inf\nf 1 2 3\nf 1 2 4\n", "non-finite vertex coordinate"),  # inf
    ],
)
def test_bad_meshes_fail_naming_object_and_leave_nothing(tmp_path, mesh_text, expect):
    mesh = tmp_path / "bad.obj"
    mesh.write_text(mesh_text)
    results = tmp_path / "results"
    cfg = write_config(
        tmp_path / "c.yaml",
        results,
        objects={
            "count": 1,
            "test_count": 1,
            "sources": ["primitives"],
            "extra": [{"path": str(mesh), "split": "train"}],
        },
        render={"resolution": 16, "spp": 1},
    )
    frng("envmaps", "--config", str(cfg))  # the object's own maps: one per object and light
    proc = frng("curate", "--config", str(cfg), "--object", "user_bad", check=False)
    assert proc.returncode != 0
    assert "user_bad" in proc.stderr and str(mesh) in proc.stderr and expect in proc.stderr, proc.stderr
    assert not (results / "objects").exists() or not any((results / "objects").iterdir())


def test_object_added_after_envmaps_fails_naming_its_map_and_the_fix(curated, tmp_path):
    """An object added to the config after `frng envmaps` ran has no maps (one per object and light): curating it
    fails in one line naming the missing map, the index and `frng envmaps`, and writes nothing."""
    tmp, _, _ = curated
    mesh = tmp_path / "mine.obj"
    mesh.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nf 1 2 3\nf 1 2 4\nf 1 3 4\nf 2 3 4\n")
    results = tmp_path / "results"
    cfg = write_config(
        tmp_path / "c.yaml",
        results,
        render={"resolution": RES},
        objects={
            "count": 2,
            "test_count": 1,
            "sources": ["primitives"],
            "extra": [{"path": str(mesh), "split": "train"}],
        },
    )
    shutil.copytree(tmp / "results" / "envmaps", results / "envmaps")  # made before the object was added
    proc = frng("curate", "--config", str(cfg), "--object", "user_mine", check=False)
    assert proc.returncode != 0
    err = proc.stderr.strip()
    assert len(err.splitlines()) == 1, err
    assert "user_mine" in err and "-user_mine'" in err and str(results / "envmaps" / "index.json") in err, err
    assert "frng envmaps" in err, err
    assert not (results / "objects").exists() or not any((results / "objects").iterdir())


# -- bit-reproducible curation (fur included) -----------------------------------------------------------------


def _exr_bytes(folder):
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*.exr"))}


def test_fur_curation_is_bit_reproducible(tmp_path):
    """Curating the same fur object twice (two processes) gives byte-identical EXRs. obj_0001 is a UV sphere: Blender's
    UV-sphere primitive and its hair-particle distribution both changed from run to run."""
    cfg = write_config(
        tmp_path / "c.yaml",
        tmp_path / "results",
        objects={
            "count": 2,
            "test_count": 1,
            "sources": ["primitives"],
            "material_mix": {"diffuse": 0.0, "specular": 0.0, "fur": 1.0},
        },
        render={
            "resolution": 16,
            "spp": 1,
            "threads": 1,
            "fur_strands": 100,
            "extra_input_views": 0,
            "target_views": 1,
        },
    )
    frng("envmaps", "--config", str(cfg))
    runs = []
    for k in range(2):
        out = tmp_path / f"run{k}"
        frng("curate", "--config", str(cfg), "--object", "obj_0001", "--out", str(out))
        runs.append(_exr_bytes(out / "obj_0001"))
    meta = io.read_json(tmp_path / "run0" / "obj_0001" / "meta.json")
    assert meta["material_class"] == "fur" and meta["shape"]["params"]["kind"] == "uv_sphere"
    assert sorted(runs[0]) == sorted(runs[1]) and len(runs[0]) == 7 + 7  # 6 + 1 views: RGBA and G-buffer each
    differ = [name for name in runs[0] if runs[0][name] != runs[1][name]]
    assert differ == [], f"{len(differ)} of {len(runs[0])} EXRs differ: {differ[:4]}"


def test_every_primitive_and_procedural_shape_is_built_identically():
    """Same kind + same random numbers -> the same vertices, faces and UVs, face order included (Blender's own
    UV-sphere primitive ordered its faces differently in every call)."""
    import bpy  # noqa: F401

    from frng.blender import objects

    def build(kind, procedural):
        make = objects.procedural if procedural else objects.primitive
        obj, _ = make(kind, np.random.default_rng(7))
        me = obj.data
        loops = np.empty(len(me.loops), np.int64)
        me.loops.foreach_get("vertex_index", loops)
        uv = np.zeros(len(me.loops) * 2, np.float32)
        if len(me.uv_layers):
            me.uv_layers[0].data.foreach_get("uv", uv)
        out = objects.vertices(obj).tobytes() + loops.tobytes() + uv.tobytes()
        bpy.data.objects.remove(obj, do_unlink=True)
        return out

    prims = ("cube", "uv_sphere", "ico_sphere", "cylinder", "cone", "torus", "monkey")
    procs = ("superquadric", "lathe", "blob", "cluster", "twisted_box")
    for kinds, procedural in ((prims, False), (procs, True)):
        for kind in kinds:
            assert build(kind, procedural) == build(kind, procedural), kind


# -- meshes with NaN/inf vertices fail, naming the file --------------------------------------------------------


def test_nonfinite_vertices_are_found_in_every_format(tmp_path):
    import struct

    pytest.importorskip("bpy")
    from frng.blender.objects import nonfinite_vertex

    cases = {
        "ok.obj": ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n", None),
        "nan.obj": ("v 0 0 0\nv 1 0 0\nv nan 1 0\nf 1 2 3\n", "line 3"),
        "inf.obj": ("# c\nv 0 0 0\nv 1 -inf 0\nv 0 1 0\nf 1 2 3\n", "line 3"),
        "nan.stl": (
            "solid t\nfacet normal 0 0 1\nouter loop\nvertex 0 0 0\nvertex 1 0 NaN\nvertex 0 1 0\n"
            "endloop\nendfacet\nendsolid t\n",
            "line 5",
        ),
        "nan.ply": (
            "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n"
            "element face 1\nproperty list uchar int vertex_indices\nend_header\n0 0 0\n1 0 0\n0 inf 0\n"
            "3 0 1 2\n",
            "vertex 3",
        ),
    }
    for name, (text, where) in cases.items():
        (tmp_path / name).write_text(text)
        found = nonfinite_vertex(tmp_path / name)
        assert (found is None) if where is None else (found is not None and where in found), (name, found)
    tri = struct.pack("<12fH", 0, 0, 1, 0, 0, 0, 1, 0, 0, 0, float("nan"), 0, 0)
    (tmp_path / "nan_bin.stl").write_bytes(b"\0" * 80 + struct.pack("<I", 1) + tri)
    assert "triangle 1" in nonfinite_vertex(tmp_path / "nan_bin.stl")
    head = (
        b"ply\nformat binary_little_endian 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
        b"property float z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n"
    )
    verts = struct.pack("<9f", 0, 0, 0, 1, 0, 0, 0, 1, float("inf"))
    (tmp_path / "inf_bin.ply").write_bytes(head + verts + struct.pack("<B3i", 3, 0, 1, 2))
    assert "vertex 3" in nonfinite_vertex(tmp_path / "inf_bin.ply")
