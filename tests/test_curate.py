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
    assert "render" in proc.stdout and "12/" not in proc.stdout  # per-image progress lines with times
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
        uv, z = camera.project(torch.tensor(pts), torch.tensor(c2w[b:b + 1]).double(), torch.tensor(K[b:b + 1]).double())
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
        assert (r < 2 * PIXEL).mean() > 0.9, f"views {a}->{b}: {(r >= 2 * PIXEL).mean():.2f} of the points float in front"
        assert (np.abs(r) < PIXEL).mean() > 0.05, f"views {a}->{b}: no shared visible surface"


def test_corrupt_envmap_fails_naming_file_and_leaves_nothing(curated, tmp_path):
    tmp, cfg, _ = curated
    env = tmp_path / "envmaps"
    shutil.copytree(tmp / "results" / "envmaps", env)
    obj = open_object(tmp / "results", "obj_0000")
    bad = env / f"{obj.input_lights[0]}.exr"
    bad.write_bytes(b"not an exr at all")
    out = tmp_path / "objects"
    proc = frng("curate", "--config", str(cfg), "--object", "obj_0000", "--envmaps", str(env), "--out", str(out),
                check=False)
    assert proc.returncode != 0
    assert str(bad) in proc.stderr and "obj_0000" in proc.stderr
    assert not out.exists() or not any(out.iterdir())


@pytest.mark.parametrize("mesh_text, expect", [
    ("v 0 0 0\nv 1 0 0\nv 1 0.0000001 0\nf 1 2 3\n", "rendered empty"),   # a sliver: loads, renders nothing
    ("this is not an obj file\n", "no mesh with faces"),
])
def test_bad_meshes_fail_naming_object_and_leave_nothing(tmp_path, curated, mesh_text, expect):
    tmp, _, _ = curated
    mesh = tmp_path / "bad.obj"
    mesh.write_text(mesh_text)
    results = tmp_path / "results"
    cfg = write_config(tmp_path / "c.yaml", results, objects={"count": 1, "test_count": 1, "sources": ["primitives"],
                                                               "extra": [{"path": str(mesh), "split": "train"}]},
                       render={"resolution": 16, "spp": 1})
    shutil.copytree(tmp / "results" / "envmaps", results / "envmaps")
    proc = frng("curate", "--config", str(cfg), "--object", "user_bad", check=False)
    assert proc.returncode != 0
    assert "user_bad" in proc.stderr and expect in proc.stderr, proc.stderr
    assert not (results / "objects").exists() or not any((results / "objects").iterdir())
