"""Numbers are checked where they enter (issue 56, docs/reliability.md): cameras, intrinsics, vertices, weights (dtype
and finiteness), maps (finite, bounded), asset fields, config values (config/schema.yaml bounds). Each probe of the
issue is a case written here; each ends in one line naming the file and the field, never in NaN intrinsics, a
"every mask is empty" misreport, a vertex silently moved to the origin or a render of 1e8.
"""

from __future__ import annotations

import copy
import json
import shutil

import numpy as np
import pytest
import torch
import yaml
from conftest import ROOT
from test_benchmarks import RES
from test_untrusted_confinement import edit_orb_frames, exported  # noqa: F401 -- the exported benchmark folders (module fixture)
from test_untrusted_outputs import tiny_asset

from frng import confine, io
from frng.apps.asset import AssetError, AssetRenderer, load_asset
from frng.benchmarks import BenchmarkError, import_scene
from frng.render import envmap


def _nerf(exported, tmp_path, edit):  # noqa: F811
    src = exported["nerf-synthetic"]
    shutil.copytree(src.parent, tmp_path / "ns")
    scene = tmp_path / "ns" / src.name
    tr = scene / "transforms_train.json"
    meta = json.loads(tr.read_text())
    edit(meta)
    tr.write_text(json.dumps(meta))
    return scene, tr


@pytest.mark.parametrize("angle", ["Infinity", "0", "NaN", "-1", '"wide"'])
def test_camera_angle_must_be_a_field_of_view(exported, tmp_path, angle):  # noqa: F811
    def edit(meta):
        meta["camera_angle_x"] = "@@"

    scene, tr = _nerf(exported, tmp_path, edit)
    tr.write_text(tr.read_text().replace('"@@"', angle))  # JSON's Infinity / NaN as Python's json reads them
    with pytest.raises(BenchmarkError, match=rf"{tr}: field 'camera_angle_x'") as err:
        import_scene("nerf-synthetic", scene, tmp_path / "r", RES, 32, extra_inputs=2)
    assert "\n" not in str(err.value) and not (tmp_path / "r" / "objects").exists()


def test_nan_transform_matrix_is_named_not_an_empty_mask(exported, tmp_path):  # noqa: F811
    def edit(meta):
        meta["frames"][3]["transform_matrix"][0][3] = float("nan")

    scene, tr = _nerf(exported, tmp_path, edit)
    with pytest.raises(BenchmarkError, match=rf"{tr}: field 'frames\[3\]\.transform_matrix' has non-finite"):
        import_scene("nerf-synthetic", scene, tmp_path / "r", RES, 32, extra_inputs=2)


def test_orb_camera_angle_of_a_novel_frame(exported, tmp_path):  # noqa: F811
    scene, nv = edit_orb_frames(exported, tmp_path, "transforms_novel.json", 0, "camera_angle_x", 0)
    with pytest.raises(BenchmarkError, match=r"field 'frames\[0\]\.camera_angle_x' must be a field of view"):
        import_scene("orb", scene, tmp_path / "r", RES, 32)


def test_gltf_nan_vertex_is_named(tmp_path):
    """Blender's glTF importer turns a NaN position into (0, 0, 0) silently; the file is checked first."""
    from test_untrusted_confinement import _gltf

    g = tmp_path / "a" / "a.gltf"
    pos = _gltf(g, "buf.bin", positions=[[0, 0, 0], [1, 0, 0], [0, np.nan, 0]])
    (g.parent / "buf.bin").write_bytes(pos.tobytes())
    assert confine.gltf_nonfinite_position(g) == "meshes[0].primitives[0] POSITION vertex 2"
    pos[2, 1] = 1.0
    (g.parent / "buf.bin").write_bytes(pos.tobytes())
    assert confine.gltf_nonfinite_position(g) is None


def test_finite_checks():
    with pytest.raises(confine.NonFiniteError, match=r"c\.json: field 'K' has non-finite"):
        confine.finite([1.0, np.inf], source="c.json", field="K")
    with pytest.raises(confine.NonFiniteError, match=r"must be 4x4, got shape \(3, 4\)"):
        confine.finite(np.eye(4)[:3], source="c.json", field="c2w", shape=(4, 4))
    with pytest.raises(confine.NonFiniteError, match="must be numbers"):
        confine.finite(["a", "b"], source="c.json", field="K")
    with pytest.raises(confine.NonFiniteError, match="must be > 0"):
        confine.finite([0.0, 1.0], source="c.json", field="focal", positive=True)
    assert confine.finite([[1, 2]], source="c", field="x", shape=(None, 2)).dtype == np.float64


# -- weights ------------------------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    "weights, words",
    [
        ({"w": torch.tensor([1.0, float("nan")])}, "non-finite"),
        ({"w": torch.tensor([1, 2], dtype=torch.int32)}, "dtype torch.int32"),
    ],
)
def test_model_file_weights_are_floating_and_finite(tmp_path, weights, words):
    path = tmp_path / "model.pt"
    io.save_torch({"kind": "frng", "config": {}, "state_dict": weights}, path)
    with pytest.raises(io.CorruptFileError, match=rf"{path}: F-RNG model file: weight 'w' has .*{words}"):
        io.load_torch(path, "F-RNG model file")
    io.load_torch(path, "checkpoint")  # other files are not model files


def test_asset_decoder_int_weights_and_ply_bounds(tmp_path):
    from safetensors.torch import save_file

    asset = tiny_asset(tmp_path / "a")
    state = load_asset(asset)[2]
    k = next(iter(state))
    state[k] = (state[k] * 1e8).to(torch.int32)
    save_file(state, str(asset / "decoder.safetensors"))
    with pytest.raises(AssetError, match=rf"decoder\.safetensors: tensor '{k}' has dtype torch.int32"):
        load_asset(asset)

    from frng.apps.asset import read_ply, write_ply

    asset = tiny_asset(tmp_path / "b")
    fields = read_ply(asset / "gaussians.ply")
    fields["scale_1"][5] = 100.0  # log scale 100: exp overflows float32
    write_ply(asset / "gaussians.ply", fields)
    with pytest.raises(AssetError, match=r"gaussians\.ply: field 'scale_1' \(log scale\) is 100 at row 5"):
        load_asset(asset)


def test_asset_with_no_gaussians(tmp_path):
    from frng.apps.asset import read_ply, write_ply

    asset = tiny_asset(tmp_path / "a")
    fields = {k: v[:0] for k, v in read_ply(asset / "gaussians.ply").items()}
    write_ply(asset / "gaussians.ply", fields)
    meta = json.loads((asset / "asset.json").read_text())
    meta["num_gaussians"] = 0
    (asset / "asset.json").write_text(json.dumps(meta))
    with pytest.raises(AssetError, match=r"asset\.json: field 'num_gaussians' is 0"):
        load_asset(asset)


# -- maps ---------------------------------------------------------------------------------------------------------


def test_env_map_of_3e38_is_refused(tmp_path):
    path = tmp_path / "sun.exr"
    img = np.ones((8, 16, 3), np.float32)
    img[2, 3] = 3e38
    envmap.write(path, img)
    with pytest.raises(envmap.EnvMapError, match=rf"{path}: environment map has a value of 3e\+38, above the limit"):
        envmap.read(path)
    img[2, 3] = envmap.MAX_RADIANCE
    envmap.write(path, img)
    assert envmap.read(path).max() == envmap.MAX_RADIANCE


def test_render_asset_with_a_3e38_light_writes_nothing(tmp_path, capsys):
    from test_untrusted_outputs import _run

    asset = tiny_asset(tmp_path / "a")
    env = tmp_path / "bright.exr"
    img = np.full((8, 16, 3), 3e38, np.float32)
    envmap.write(env, img)
    code, lines = _run(["render-asset", asset, "--env", env, "--out", tmp_path / "o", "--turntable", 2], capsys)
    assert code == 2 and len(lines) == 1 and str(env) in lines[0] and "above the limit" in lines[0], lines
    assert not (tmp_path / "o").exists()


def test_asset_renders_finite(tmp_path):
    """The tiny asset the cases above corrupt renders finite values when intact (the checks refuse only bad ones)."""
    r = AssetRenderer(tiny_asset(tmp_path / "a"))
    from frng import camera

    c2w = torch.tensor(camera.look_at(camera.spherical_to_cartesian(0.0, 20.0, 3.0)), dtype=torch.float32)[None]
    intr = torch.tensor(camera.intrinsics_from_fov(40.0, 16, 16), dtype=torch.float32)[None]
    out = r.render(torch.ones(8, 16, 3), c2w, intr, 16, 16, spp=4)
    assert out.shape == (1, 16, 16, 4) and torch.isfinite(out).all() and out[..., 3].max() > 0


# -- config bounds (config/schema.yaml) ----------------------------------------------------------------------------


@pytest.mark.parametrize(
    "key, value, words",
    [
        ("train.lr", float("inf"), "greater than the maximum"),
        ("train.lr", float("nan"), "should not be valid"),
        ("render.spp", 10**12, "greater than the maximum"),
        ("shading.spp_infer", 10**9, "greater than the maximum"),
        ("render.resolution", 8 * 10**6, "greater than the maximum"),
        ("envmaps.width", 33, "not a multiple of 2"),
    ],
)
def test_config_values_are_bounded(key, value, words):
    from frng.plan import config
    from frng.plan.sections import ConfigError

    base = yaml.safe_load((ROOT / "config" / "smoke.yaml").read_text())
    c = copy.deepcopy(base)
    section, name = key.split(".")
    c.setdefault(section, {})[name] = value
    with pytest.raises(ConfigError, match=rf"config key '{key}': .*{words}"):
        config.validate(c)
