"""Users' own assets through config keys only: a box mesh (OBJ, Y-up) and env maps the test writes itself."""

import numpy as np
import pytest
import torch
from data_helpers import frng, write_config

from frng import camera, io
from frng.data.dataset import open_object
from frng.render import envmap

pytestmark = pytest.mark.blender

BOX = np.array([[x, y, z] for x in (-1.0, 1.0) for y in (-0.5, 0.5) for z in (-0.25, 0.25)])  # file coords, Y-up


def write_box_obj(path):
    lines = [f"v {x} {y} {z}" for x, y, z in BOX]
    quads = [(1, 2, 4, 3), (5, 7, 8, 6), (1, 5, 6, 2), (3, 4, 8, 7), (1, 3, 7, 5), (2, 6, 8, 4)]
    lines += [f"f {a} {b} {c} {d}" for a, b, c, d in quads]
    path.write_text("\n".join(lines) + "\n")


def write_sky(path, h=32, sun_az=30.0):
    d = envmap.pixel_directions(h, 2 * h, dtype=torch.float64).numpy()
    sun = camera.spherical_to_cartesian(sun_az, 40.0, 1.0)
    rad = 0.3 + 0.5 * np.clip(d[..., 2:3], 0, 1) + 20.0 * (d @ sun > 0.97)[..., None]
    envmap.write(path, np.repeat(rad, 3, -1).astype(np.float32) * np.array([0.9, 1.0, 1.1], np.float32))


def test_user_mesh_and_envmaps_are_curated(tmp_path):
    meshes, skies = tmp_path / "meshes", tmp_path / "skies"
    meshes.mkdir(), skies.mkdir()
    write_box_obj(meshes / "Box.obj")
    write_sky(skies / "a.exr", sun_az=30.0)
    write_sky(tmp_path / "b.exr", sun_az=200.0)
    cfg = write_config(
        tmp_path / "config.yaml",
        tmp_path / "results",
        objects={
            "count": 1,
            "test_count": 0,
            "sources": ["primitives"],
            "extra": [{"path": str(meshes), "split": "test", "material": "specular", "licence": "CC0 (test)"}],
        },
        envmaps={
            "bundled": [],
            "skies": {"models": []},
            "width": 32,
            "rotations": 1,
            "extra": [{"path": str(skies), "split": "train"}, {"path": str(tmp_path / "b.exr"), "split": "test"}],
        },
        render={"resolution": 32, "spp": 2},
    )
    frng("envmaps", "--config", str(cfg))
    index = io.read_json(tmp_path / "results" / "envmaps" / "index.json")
    assert {(m["base"], m["source"], m["split"]) for m in index["maps"]} == {
        ("user_a", "user", "train"),
        ("user_b", "user", "test"),
    }
    frng("curate", "--config", str(cfg), "--object", "user_box")

    obj = open_object(tmp_path / "results", "user_box")
    meta = obj.meta
    assert (meta["source"], meta["split"], meta["material_class"], meta["licence"]) == (
        "user",
        "test",
        "specular",
        "CC0 (test)",
    )
    assert obj.input_lights == ["user_b_r0-user_box"] and all(l == "user_b_r0-user_box" for l in obj.target_lights)

    # The box's corners, mapped file -> world with the recorded transform, project onto the silhouette's bbox.
    m = np.asarray(meta["shape"]["file_to_world"])
    corners = BOX @ m[:3, :3].T + m[:3, 3]
    assert np.isclose(np.linalg.norm(corners, axis=1).max(), 1.0, atol=1e-6)
    ext = corners.max(0) - corners.min(0)
    assert np.isclose(ext[2] / ext[0], 0.5) and np.isclose(ext[1] / ext[0], 0.25)  # file Y is world Z
    c2w, K = obj.cameras("inputs")
    alpha = obj.gbuffer("inputs")["alpha"][..., 0]
    uv, _ = camera.project(torch.tensor(corners), torch.tensor(c2w).double(), torch.tensor(K).double())
    for v in range(len(c2w)):
        rows, cols = np.nonzero(alpha[v] > 0.5)
        got = np.array([cols.min(), rows.min(), cols.max() + 1, rows.max() + 1], float)
        want = np.array([uv[v, :, 0].min(), uv[v, :, 1].min(), uv[v, :, 0].max(), uv[v, :, 1].max()])
        assert np.abs(got - want).max() <= 1.0, f"view {v}: silhouette bbox {got}, projected corners {want}"
