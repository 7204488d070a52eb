"""Public benchmarks (frng/benchmarks): every published layout round-trips export -> import with its camera and
map conventions (a known 3D point lands on a known pixel), bad input is one line naming the file with nothing left
behind, and each published metric protocol reproduces a value computed by hand on a tiny example."""

from __future__ import annotations

import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from frng import camera, io
from frng.benchmarks import BenchmarkError, export_object, import_scene, protocols
from frng.benchmarks.common import map_directions
from frng.render import envmap

RES = 32
RIG = [(0, 0), (90, 0), (180, 0), (270, 0), (45, 45), (225, 45)]
EXTRA = [(30, 20), (200, -20)]
TARGETS = [(60, 10), (300, 30)]
LIGHTS_IN, LIGHTS_TGT = ["sun_a"], ["sky_b", "sky_c"]
LAYOUTS = ["tensoir", "nerf-synthetic", "orb", "owl"]


def _smooth_map(seed: int, h: int = 16) -> np.ndarray:
    rng = np.random.default_rng(seed)
    d = map_directions(h)
    a = rng.normal(size=(3, 3))
    return (1.2 + 0.5 * np.tanh(d @ a)).astype(np.float32)


def _render(c2w, K, light_seed: int) -> np.ndarray:
    """A sphere of radius 0.7 at the origin, Lambertian-ish under a light-dependent direction, 2x2 supersampled."""
    rng = np.random.default_rng(light_seed)
    ldir = rng.normal(size=3)
    ldir /= np.linalg.norm(ldir)
    colour = np.array([0.8, 0.5, 0.3]) * (0.5 + rng.random(3))
    img = np.zeros((RES, RES, 4))
    for sy in (0.25, 0.75):
        for sx in (0.25, 0.75):
            u, v = np.meshgrid(np.arange(RES) + sx, np.arange(RES) + sy)
            d = np.stack([(u - K[2]) / K[0], (v - K[3]) / K[1], np.ones_like(u)], -1) @ c2w[:3, :3].T
            d /= np.linalg.norm(d, axis=-1, keepdims=True)
            o = c2w[:3, 3]
            b = d @ o
            disc = b * b - (o @ o - 0.49)
            hit = disc > 0
            t = -b - np.sqrt(np.maximum(disc, 0))
            n = (o + t[..., None] * d) / 0.7
            shade = (0.2 + np.maximum(n @ ldir, 0))[..., None] * colour
            img[..., :3] += np.where(hit[..., None], shade, 0) / 4
            img[..., 3] += hit / 4
    return img.astype(np.float32)


def _cam(az, el, kind, name):
    c2w = camera.look_at(camera.spherical_to_cartesian(az + 17.0, el, 2.6))
    K = camera.intrinsics_from_fov(50.0, RES, RES)
    return {
        "name": name,
        "kind": kind,
        "azimuth_deg": az,
        "elevation_deg": el,
        "c2w": c2w.tolist(),
        "intrinsics": K.tolist(),
        "width": RES,
        "height": RES,
    }


def make_curated(results: Path, oid: str = "obj_0000") -> Path:
    """A curated object in the dataset contract, drawn analytically (no Blender)."""
    for k, name in enumerate(LIGHTS_IN + LIGHTS_TGT):
        envmap.write(results / "envmaps" / f"{name}.exr", _smooth_map(k))
    views = {
        "inputs": [_cam(a, e, "input", f"in_{k:02d}") for k, (a, e) in enumerate(RIG + EXTRA)],
        "targets": [_cam(a, e, "target", f"tgt_{k:03d}") for k, (a, e) in enumerate(TARGETS)],
    }
    root = results / "objects" / oid
    for kind, lights in (("inputs", LIGHTS_IN), ("targets", LIGHTS_TGT)):
        for li, light in enumerate(lights):
            for v in views[kind]:
                img = _render(np.array(v["c2w"]), v["intrinsics"], 10 + li + (5 if kind == "targets" else 0))
                io.write_exr(root / kind / light / f"{v['name']}.exr", img, channels=["R", "G", "B", "A"])
    io.write_json(
        root / "meta.json",
        {
            "id": oid,
            "split": "test",
            "material_class": "diffuse",
            "input_lights": LIGHTS_IN,
            "target_lights": LIGHTS_TGT,
            "views": views,
            "lights": {n: {"file": f"envmaps/{n}.exr"} for n in LIGHTS_IN + LIGHTS_TGT},
        },
    )
    return root


@pytest.fixture(scope="module")
def curated(tmp_path_factory):
    results = tmp_path_factory.mktemp("bench") / "results"
    make_curated(results)
    return results


@pytest.fixture(scope="module")
def round_trips(curated, tmp_path_factory):
    out = {}
    for layout in LAYOUTS:
        base = tmp_path_factory.mktemp(layout.replace("-", "_"))
        path = export_object(layout, curated, "obj_0000", base / "export")
        folder = import_scene(layout, path, base / "results", RES, 32, extra_inputs=2)
        out[layout] = (path, folder, io.read_json(folder / "meta.json"), base / "results")
    return out


def _project(c2w, K, X):
    p = np.linalg.inv(np.asarray(c2w))[:3] @ np.append(X, 1.0)
    return np.array([K[0] * p[0] / p[2] + K[2], K[1] * p[1] / p[2] + K[3]])


@pytest.mark.parametrize("layout", LAYOUTS)
def test_cameras_round_trip_a_known_point_to_a_known_pixel(layout, curated, round_trips):
    _, _, meta, _ = round_trips[layout]
    src = io.read_json(curated / "objects" / "obj_0000" / "meta.json")
    T = np.array(meta["benchmark"]["source_to_world"])
    # the object's centre (the origin) is at the image centre of every look-at camera: a known pixel
    for v in meta["views"]["inputs"] + meta["views"]["targets"]:
        assert np.allclose(
            _project(v["c2w"], v["intrinsics"], (T @ [0, 0, 0, 1])[:3]), [RES / 2, RES / 2], atol=2e-3
        ), (layout, v["name"])
    # an off-centre point lands where the original camera puts it
    X = np.array([0.31, -0.22, 0.45])
    Xn = (T @ np.append(X, 1))[:3]
    # ORB/OWL: one target view per (light, camera), the export repeats the cameras per light
    src_t = {f"tgt_{k:03d}": src["views"]["targets"][k % len(TARGETS)] for k in range(2 * len(TARGETS))}
    if layout == "nerf-synthetic":  # its test views are the extra input views (one light: novel views)
        src_t = {f"tgt_{k:03d}": v for k, v in enumerate(src["views"]["inputs"][6:])}
    for v in meta["views"]["targets"]:
        assert np.allclose(
            _project(v["c2w"], v["intrinsics"], Xn),
            _project(src_t[v["name"]]["c2w"], src_t[v["name"]]["intrinsics"], X),
            atol=2e-3,
        ), (layout, v["name"])
    # normalised into the unit sphere: the sphere of radius 0.7 fills it (silhouette-cone radius, area sampled)
    scale = np.cbrt(np.linalg.det(T[:3, :3]))
    assert 1.0 / 0.8 < scale < 1.0 / 0.6, scale
    assert np.allclose(T[:3, 3], 0, atol=1e-6)


def test_rig_like_input_views(round_trips):
    _, _, meta, _ = round_trips["tensoir"]
    src = [Path(s).parent.name for s in meta["benchmark"]["input_views_from"]]
    assert src[:6] == [f"train_{k:03d}" for k in range(6)]  # the rig's own views, in rig order
    assert sorted(src[6:]) == ["train_006", "train_007"]  # then the extras, farthest point first
    assert [v["name"] for v in meta["views"]["inputs"]] == [f"in_{k:02d}" for k in range(8)]


@pytest.mark.parametrize("layout", LAYOUTS)
def test_images_and_lights_round_trip(layout, curated, round_trips):
    _, folder, meta, results = round_trips[layout]
    src = curated / "objects" / "obj_0000"
    oid = meta["id"]
    assert meta["split"] == "test" and meta["benchmark"]["protocol"] == layout in protocols.PROTOCOLS
    pairs = meta["benchmark"]["pairs"]
    assert pairs
    tol = {"tensoir": 0.03, "nerf-synthetic": 0.03, "orb": 3e-3, "owl": 0.03}[layout]  # 8-bit PNGs / masks
    if layout == "nerf-synthetic":  # a novel-view benchmark: the extra input views under the input light
        for k, name in enumerate(["in_06", "in_07"]):
            got = io.read_rgba(folder / "targets" / pairs[k][0] / f"tgt_{k:03d}.exr")
            want = io.read_rgba(src / "inputs" / LIGHTS_IN[0] / f"{name}.exr")
            assert np.abs(got - want).max() < tol, layout
    else:
        light_of = {l: LIGHTS_TGT[i] for i, l in enumerate(meta["target_lights"])} if layout != "owl" else None
        for light, view in pairs:
            if layout == "owl":  # one light per test view, in (light, view) export order
                src_light = LIGHTS_TGT[int(light.rsplit("_", 1)[1]) // len(TARGETS)]
            elif layout == "tensoir":
                src_light = light.split(f"{oid}_", 1)[1]
            else:
                src_light = light_of[light]
            got = io.read_rgba(folder / "targets" / light / f"{view}.exr")
            want = io.read_rgba(src / "targets" / src_light / f"tgt_{int(view[4:]) % len(TARGETS):03d}.exr")
            assert np.abs(got - want).max() < tol, (layout, light, view, np.abs(got - want).max())
            m = envmap.read(results / meta["lights"][light]["file"])
            w = envmap.read(curated / "envmaps" / f"{src_light}.exr")
            assert np.abs(m - w).max() / w.max() < (0.03 if layout == "orb" else 0.01), (layout, light)
    inp = envmap.read(results / meta["lights"][meta["input_lights"][0]]["file"])
    want = envmap.read(curated / "envmaps" / f"{LIGHTS_IN[0]}.exr")
    assert np.abs(inp - want).max() / want.max() < 0.03, layout


def test_imported_object_reads_with_the_dataset_reader(round_trips):
    from frng.data.dataset import ObjectData

    _, folder, meta, _ = round_trips["orb"]
    obj = ObjectData.open(folder)
    c2w, K = obj.cameras("inputs", 6)
    assert c2w.shape == (6, 4, 4) and K.shape == (6, 4)
    img = obj.images("inputs", obj.input_lights[0], 6)
    assert img.shape == (6, RES, RES, 4) and img[..., 3].max() == pytest.approx(1.0, abs=1e-3)


# -- bad input --------------------------------------------------------------------------------------------------


def _no_leftovers(results: Path):
    objs = results / "objects"
    return not objs.exists() or not any(objs.iterdir())


def test_missing_file_names_it_and_leaves_nothing(round_trips, tmp_path):
    import shutil

    path = round_trips["tensoir"][0]
    bad = tmp_path / "scene"
    shutil.copytree(path, bad)
    shutil.copytree(path.parent / "light_probes", tmp_path / "light_probes")
    (bad / "test_001" / "metadata.json").unlink()
    with pytest.raises(BenchmarkError, match=r"test_001/metadata\.json"):
        import_scene("tensoir", bad, tmp_path / "r", RES, 32)
    assert _no_leftovers(tmp_path / "r")


def test_wrong_layout(round_trips, tmp_path):
    path = round_trips["tensoir"][0]
    with pytest.raises(BenchmarkError, match=r"transforms_train\.json"):
        import_scene("orb", path, tmp_path / "r", RES, 32)
    with pytest.raises(BenchmarkError, match=r"not the TensoIR layout"):
        import_scene("tensoir", round_trips["nerf-synthetic"][0], tmp_path / "r", RES, 32)
    assert _no_leftovers(tmp_path / "r")


def test_map_not_2_to_1(round_trips, tmp_path):
    import shutil

    path = round_trips["tensoir"][0]
    shutil.copytree(path, tmp_path / "scene")
    shutil.copytree(path.parent / "light_probes", tmp_path / "light_probes")
    from frng.io import write_hdr

    write_hdr(tmp_path / "light_probes" / "sky_b.hdr", np.ones((16, 16, 3), np.float32))
    with pytest.raises(BenchmarkError, match=r"sky_b\.hdr.*2:1"):
        import_scene("tensoir", tmp_path / "scene", tmp_path / "r", RES, 32)
    assert _no_leftovers(tmp_path / "r")


def test_images_of_different_sizes(round_trips, tmp_path):
    import shutil

    path = round_trips["nerf-synthetic"][0]
    shutil.copytree(path, tmp_path / "scene")
    io.write_png(tmp_path / "scene" / "train" / "r_3.png", np.zeros((16, 16, 4), np.float32))
    with pytest.raises(BenchmarkError, match=r"r_3\.png.*different sizes"):
        import_scene("nerf-synthetic", tmp_path / "scene", tmp_path / "r", RES, 32)
    assert _no_leftovers(tmp_path / "r")


def test_cli_error_is_one_line(round_trips, tmp_path):
    from tests.data_helpers import write_config

    cfg = write_config(tmp_path / "c.yaml", tmp_path / "r")
    proc = subprocess.run(
        [sys.executable, "-m", "frng", "import", "owl", str(tmp_path / "nowhere"), "--config", str(cfg)],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert proc.returncode == 2
    lines = [l for l in (proc.stdout + proc.stderr).splitlines() if l.strip()]
    assert len(lines) == 1 and "nowhere" in lines[0], lines


# -- the published protocols, by hand -------------------------------------------------------------------------


def _srgb(x):
    return 12.92 * x if x <= 0.0031308 else 1.055 * x ** (1 / 2.4) - 0.055


def test_tensoir_protocol_by_hand():
    # 12 x 12, half the pixels object (alpha 1), half background; prediction off by 0.1 (sRGB) on the object
    gt = np.zeros((12, 12, 4), np.float32)
    gt[:6, :, :3], gt[:6, :, 3] = 0.2, 1.0
    pred = gt.copy()
    g = _srgb(0.2)
    pred[:6, :, :3] = ((g + 0.1 + 0.055) / 1.055) ** 2.4  # sRGB-encodes to g + 0.1
    out = protocols.tensoir(pred, gt, lpips=False)
    # whole image on white: the background matches, the object's half is off by 0.1 in every channel
    assert out["psnr"] == pytest.approx(-10 * math.log10(0.5 * 0.01), abs=1e-3)
    assert protocols.tensoir(gt, gt, lpips=False)["ssim"] == pytest.approx(1.0)


def test_orb_protocol_by_hand():
    # all-foreground 12 x 12 (the 5x5 erosion keeps it: OpenCV's border does not erode), gt 0.5 everywhere,
    # prediction 0.25 on half the pixels and 0.5 on the other half
    gt = np.full((12, 12, 4), 0.5, np.float32)
    gt[..., 3] = 1.0
    pred = gt.copy()
    pred[:6, :, :3] = 0.25
    s = (0.5 * 0.25 + 0.5 * 0.5) / (0.25**2 + 0.5**2)  # least-squares scale per channel = 1.2
    e1, e2 = s * 0.25 - 0.5, s * 0.5 - 0.5  # -0.2, +0.1
    # PSNR-H: both x median factor m = srgb(0.5) / 0.5 first, max 4, no tone mapping
    m = _srgb(0.5) / 0.5
    mse_h = 0.5 * ((m * e1) ** 2 + (m * e2) ** 2)
    # PSNR-L: no median, clip to 1, sRGB both
    mse_l = 0.5 * ((_srgb(s * 0.25) - _srgb(0.5)) ** 2 + (_srgb(s * 0.5) - _srgb(0.5)) ** 2)
    out = protocols.orb(pred, gt)
    assert s == pytest.approx(1.2)
    assert out["psnr_h"] == pytest.approx(-10 * math.log10(mse_h), abs=1e-4)
    assert out["psnr_l"] == pytest.approx(-10 * math.log10(mse_l), abs=1e-4)
    assert out["psnr"] == out["psnr_h"]
    # the lower bound: a constant 0.5 image scores at least max(out, psnr(0.5 x mask vs gt)); the erosion
    m5 = np.zeros((12, 12), np.float32)
    m5[3:9, 3:9] = 1
    assert protocols.orb_erode(m5).sum() == 4  # 6x6 block eroded by a 5x5 box: 2x2 left


def test_owl_protocol_by_hand():
    # gt (tone-mapped) = 3 pixels at (0.25 * 2)^(1/2.2) and 1 at 0.9; prediction linear 0.25 everywhere:
    # the best exposure (L1) is 1 (the weighted median), colour balance 1, so 1 of 4 pixels is off by 0.9 - g1
    g1 = (0.25 * 2) ** (1 / 2.2)
    gt_tm = np.full((2, 2, 3), g1, np.float32)
    gt_tm[1, 1] = 0.9
    gt_lin = np.concatenate([np.power(gt_tm, 2.2), np.ones((2, 2, 1), np.float32)], -1)  # exposure 0
    pred = np.full((2, 2, 4), 0.25, np.float32)
    pred[..., 3] = 1
    out = protocols.owl(pred, gt_lin, exposure=0.0, lpips=False)
    assert out["exposure_fit"] == pytest.approx(1.0, abs=1e-3)
    assert out["psnr"] == pytest.approx(-10 * math.log10(0.25 * (0.9 - g1) ** 2), abs=1e-2)
    # over-exposed ground-truth pixels are left out of the fit
    p, e, bal = protocols.owl_fit(
        np.full((2, 2, 3), 0.25, np.float32), np.where(gt_tm == 0.9, 1.0, gt_tm), np.ones((2, 2, 1))
    )
    assert e == pytest.approx(1.0, abs=1e-3) and np.allclose(bal, 1, atol=1e-3)
