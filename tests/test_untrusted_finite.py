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
        ("train.lr", float("inf"), "not a finite number"),
        ("train.lr", float("nan"), "not a finite number"),
        ("render.target_views", 10**6, "greater than the maximum"),
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


# -- issue 87, probe 7: every number of the config is finite; sizes bounded; a key given twice refused ------------------


def _number_keys(node: dict, path: tuple = ()) -> list[tuple]:
    """The dotted paths of every number key of the schema (``type`` number or integer, alone or with null), list
    items as index 0."""
    out = []
    types = node.get("type")
    types = types if isinstance(types, list) else [types]
    if path and ("number" in types or "integer" in types):
        out.append(path)
    for name, sub in (node.get("properties") or {}).items():
        if isinstance(sub, dict):
            out += _number_keys(sub, (*path, name))
    if isinstance(node.get("items"), dict):
        out += _number_keys(node["items"], (*path, 0))
    return out


def _put(config: dict, path: tuple, value) -> None:
    """Set ``path`` in ``config``, making the sections and one-item lists on the way (list items: copies of the
    smallest valid item are not needed: the finite rule refuses before the schema looks at them)."""
    node = config
    for i, p in enumerate(path[:-1]):
        nxt = path[i + 1]
        if isinstance(p, int):
            while len(node) <= p:
                node.append({} if not isinstance(nxt, int) else [])
            node = node[p]
            continue
        if not isinstance(node.get(p), (dict, list)) or (isinstance(nxt, int) != isinstance(node.get(p), list)):
            node[p] = [] if isinstance(nxt, int) else {}
        node = node[p]
    last = path[-1]
    if isinstance(last, int):
        node[:] = [value]
    else:
        node[last] = value


def test_every_number_key_of_the_schema_refuses_nan_and_inf():
    from frng.confine import dotted
    from frng.plan import config
    from frng.plan.sections import ConfigError, load_schema

    keys = _number_keys(load_schema())
    assert len(keys) > 150, len(keys)
    base = yaml.safe_load((ROOT / "config" / "smoke.yaml").read_text())
    for path in keys:
        for bad in (float("nan"), float("inf"), float("-inf")):
            c = copy.deepcopy(base)
            _put(c, path, bad)
            with pytest.raises(ConfigError, match="not a finite number") as err:
                config.validate(c)
            assert f"config key '{dotted(path)}'" in str(err.value), (path, str(err.value))


def test_probe_7_nan_keys_and_sizes(tmp_path):
    """The keys the probe set to NaN / inf (they passed validation, the dry run and the stages), from a YAML file."""
    from frng.plan import config
    from frng.plan.sections import ConfigError

    text = (ROOT / "config" / "smoke.yaml").read_text()
    for key, value in (
        ("idm.train.head_lr", ".nan"),
        ("idm.train.geo_lr", ".inf"),
        ("train.loss.lambda_per", ".nan"),
        ("backbone.near", ".nan"),
        ("backbone.train.grad_clip", ".inf"),
        ("train.weight_decay", ".nan"),
        ("idm.depth_range", ".nan"),
    ):
        c = yaml.safe_load(text)
        node = c
        for part in key.split(".")[:-1]:
            node = node.setdefault(part, {})
        node[key.split(".")[-1]] = "@@"
        f = tmp_path / "c.yaml"
        f.write_text(yaml.safe_dump(c).replace("'@@'", value))
        with pytest.raises(ConfigError, match=rf"config key '{key}': (nan|inf) is not a finite number"):
            config.load(f)


def test_duplicate_yaml_key_is_refused_naming_it(tmp_path):
    from frng.plan import config
    from frng.plan.sections import ConfigError

    f = tmp_path / "c.yaml"
    f.write_text("tier: smoke\ntrain:\n  lr: 0.001\n  steps: 3\n  lr: 10\n")
    with pytest.raises(
        ConfigError, match=r"c\.yaml, line 5 column 3: invalid YAML \(duplicate key 'lr' \(first given on line 3"
    ):
        config.read_yaml(f)
    f.write_text("tier: smoke\ntier: paper\n")
    with pytest.raises(ConfigError, match=r"duplicate key 'tier'"):
        config.load(f)


@pytest.mark.parametrize(
    "arch, words",
    [
        ({"hidden": 300000}, r"field 'config\.hidden' is 300000; must be in 0\.\.8192"),
        ({"geo_dim": 10**9}, r"field 'config\.geo_dim' is 1000000000; must be in 0\.\.8192"),
        ({"saliency": {"box_size": 10**7}}, r"field 'config\.saliency\.box_size' is 10000000"),
        ({"near": float("nan")}, r"field 'config\.near' is not a finite number"),
        ({"depth": -3}, r"field 'config\.depth' is -3"),
    ],
)
def test_model_file_architecture_sizes_are_bounded(tmp_path, arch, words):
    path = tmp_path / "model.pt"
    io.save_torch({"config": {"hidden": 64, **arch}, "state_dict": {"w": torch.ones(2)}}, path)
    with pytest.raises(io.CorruptFileError, match=rf"{path}: F-RNG model file: {words}") as err:
        io.load_torch(path, "F-RNG model file")
    assert "\n" not in str(err.value)


# -- issue 87, probe 6: silent wrong output -----------------------------------------------------------------------


def test_probe_6_silent_wrong_renders_are_errors(tmp_path, capsys):
    from test_untrusted_outputs import _env, _run

    asset = tiny_asset(tmp_path / "a")
    env = _env(tmp_path / "env.exr")
    out = tmp_path / "o"
    base = ["render-asset", asset, "--env", env, "--out", out, "--spp", 1, "--video", "none"]
    # --turntable 0 rendered the default 24 views
    code, lines = _run([*base, "--turntable", 0], capsys)
    assert code == 2 and len(lines) == 1 and "--turntable 0: N must be 1..1000" in lines[0], lines
    # an all-negative map rendered black
    neg = tmp_path / "neg.exr"
    envmap.write(neg, np.full((8, 16, 3), -1.0, np.float32))
    code, lines = _run([*base[:3], neg, *base[4:], "--turntable", 1], capsys)
    assert code == 2 and len(lines) == 1 and f"{neg}: environment map has only negative" in lines[0], lines
    # asset.json rig.fov_deg NaN rendered all-zero frames (json reads NaN); a zero one too
    meta_path = asset / "asset.json"
    meta = json.loads(meta_path.read_text())
    for fov, words in (
        (float("nan"), "field 'rig.fov_deg' is not a finite number"),
        (0.0, "field 'rig.fov_deg' is 0.0"),
    ):
        meta["rig"]["fov_deg"] = fov
        meta_path.write_text(json.dumps(meta))
        code, lines = _run([*base, "--turntable", 1], capsys)
        assert code == 2 and len(lines) == 1 and f"{meta_path}: {words}" in lines[0], lines
    meta["rig"]["fov_deg"] = 40.0
    meta_path.write_text(json.dumps(meta))


@pytest.mark.parametrize(
    "fill, words",
    [
        ((0.0, 0.0), "no turntable view sees the asset"),  # empty frames (cameras 1e30 away, looking past it)
        ((0.0, 1.0), "every view renders black under"),  # covered but black under a light that is not black
        ((float("nan"), 1.0), "the render of view 'turn_000' has non-finite values"),
    ],
)
def test_renders_empty_black_or_nan_are_errors(tmp_path, capsys, monkeypatch, fill, words):
    from test_untrusted_outputs import _env, _run

    asset = tiny_asset(tmp_path / "a")
    out = tmp_path / "o"

    def render(self, env, c2w, intr, h, w, spp=None, generator=None, **k):
        img = torch.full((len(c2w), h, w, 4), fill[0])
        img[..., 3] = fill[1]
        return img

    monkeypatch.setattr(AssetRenderer, "render", render)
    argv = ["render-asset", asset, "--env", _env(tmp_path / "e.exr"), "--out", out, "--turntable", 2, "--video", "none"]
    code, lines = _run(argv, capsys)
    assert code == 2 and len(lines) == 1 and words in lines[0] and "nothing was written" in lines[0], lines
    assert not out.exists() and not list(tmp_path.glob(".tmp-*"))


@pytest.mark.parametrize(
    "edit, words",
    [
        (lambda f: f.update(camera_angle_x=0), "field 'frames[0].camera_angle_x' must be a field of view"),
        (lambda f: f.update(camera_angle_x=np.pi), "field 'frames[0].camera_angle_x' must be a field of view"),
        (lambda f: f.update(camera_angle_x=np.pi - 1e-9), "field of view 180 deg"),
        (lambda f: f["transform_matrix"][0].__setitem__(3, 1e30), "camera is 1e+30 from the origin"),
        (lambda f: f.update(transform_matrix=[[0, 0, 0, 0]] * 3 + [[0, 0, 0, 1]]), "its rotation is singular"),
    ],
)
def test_camera_files_degenerate_cameras_are_one_line(tmp_path, capsys, edit, words):
    """A --cameras file (transforms.json) whose field of view is 0 (ZeroDivisionError) or pi (fx = 2.6e-14 stored),
    whose camera is 1e30 away or whose matrix is singular (LinAlgError): one line naming the file, exit 2."""
    from test_untrusted_outputs import _env, _run

    from frng import camera

    frame = {"file_path": "v0", "w": 16, "h": 16, "camera_angle_x": 0.7}
    frame["transform_matrix"] = camera.look_at(camera.spherical_to_cartesian(0.0, 20.0, 3.0)).tolist()
    edit(frame)
    cams = tmp_path / "transforms.json"
    cams.write_text(json.dumps({"frames": [frame]}))
    asset = tiny_asset(tmp_path / "a")
    argv = ["render-asset", asset, "--env", _env(tmp_path / "e.exr"), "--out", tmp_path / "o", "--cameras", cams]
    code, lines = _run(argv, capsys)
    assert code == 2 and len(lines) == 1 and f"{cams}: " in lines[0] and words in lines[0], lines
    assert not (tmp_path / "o").exists()
