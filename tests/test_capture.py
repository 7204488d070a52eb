"""frng.apps.capture and the render side of assets, without trained models: photos, masks, camera files, framing, the
light estimate, every bad input of `frng reconstruct` / `frng render-asset` (one line naming the file), and a
synthetic asset rendered to views and a turntable GIF."""

from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch
from conftest import ROOT

from frng import camera, io
from frng.apps.capture import (
    CaptureError,
    estimate_light,
    load_images,
    make_masks,
    prepare,
    read_light,
    rig_cameras,
)
from frng.render import envmap

RES, DIST, FOV = 32, 4.0, 30.0


def _disk(res=RES, r=0.3, colour=(0.8, 0.3, 0.2), bg=None, cx=0.5, cy=0.5):
    """A disk, as straight-alpha RGBA in [0, 1] (bg: an opaque background colour instead of alpha)."""
    y, x = np.mgrid[0:res, 0:res] + 0.5
    inside = ((x / res - cx) ** 2 + (y / res - cy) ** 2) < r * r
    img = np.zeros((res, res, 4), np.float32)
    img[inside, :3] = colour
    img[..., 3] = inside
    if bg is not None:
        img[~inside, :3] = bg
        img[..., 3] = 1.0
    return img


def _png(path: Path, img: np.ndarray):
    io.write_png(path, img)
    return path


def _folder(tmp, n=3, **kw) -> Path:
    d = tmp / "images"
    d.mkdir(exist_ok=True)
    for i in range(n):
        _png(d / f"v{i}.png", _disk(**kw))
    return d


# -- images, masks -------------------------------------------------------------------------------------------


def test_fewer_than_two_images_names_the_folder(tmp_path):
    d = _folder(tmp_path, n=1)
    with pytest.raises(CaptureError, match=f"{d}: 1 image.*at least 2"):
        load_images(d)


def test_images_of_different_aspect_ratios_name_the_file(tmp_path):
    d = _folder(tmp_path, n=2)
    _png(d / "v9.png", np.ones((RES, 2 * RES, 4), np.float32))
    with pytest.raises(CaptureError, match=r"v9.png: aspect ratio 64x32 differs"):
        load_images(d)


def test_grid_image_is_split_row_by_row(tmp_path):
    tiles = [_disk(colour=(0.1 * k, 0.2, 0.3)) for k in range(6)]
    grid = np.concatenate([np.concatenate(tiles[:3], 1), np.concatenate(tiles[3:], 1)], 0)
    f = _png(tmp_path / "grid.png", grid)
    photos = load_images(f, grid=(2, 3))
    assert [p.name for p in photos] == [f"grid_r{i}c{j}" for i in range(2) for j in range(3)]
    assert all(p.size == (RES, RES) and p.alpha is not None for p in photos)
    straight = photos[4].rgb[16, 16] / photos[4].alpha[16, 16]
    assert np.allclose(io.srgb_encode(straight), (0.4, 0.2, 0.3), atol=0.01)
    # one grid mask beside one grid image is split the same way
    masks = tmp_path / "masks"
    masks.mkdir()
    m = np.zeros((2 * RES, 3 * RES, 3), np.float32)
    m[RES:, 2 * RES :] = 1.0  # only the last tile
    _png(masks / "grid.png", m)
    with pytest.raises(CaptureError, match=r"grid.png: the mask is empty"):
        make_masks(load_images(f, grid=(2, 3)), masks, grid=(2, 3))
    m[:] = 1.0
    _png(masks / "grid.png", m)
    assert all(p.alpha.min() == 1.0 for p in make_masks(load_images(f, grid=(2, 3)), masks, grid=(2, 3)))


def test_masks_from_alpha_folder_and_keyed_background(tmp_path):
    want = _disk()[..., 3] > 0.5
    photos = make_masks(load_images(_folder(tmp_path, n=2)))
    assert [p.mask_source for p in photos] == ["alpha", "alpha"]
    assert ((photos[0].alpha > 0.5) == want).all()
    # uniform grey background, no alpha: keyed out, colours unmixed
    keyed = tmp_path / "keyed"
    keyed.mkdir()
    for i in range(2):
        _png(keyed / f"k{i}.png", _disk(bg=(0.5, 0.5, 0.5))[..., :3])
    photos = make_masks(load_images(keyed))
    assert [p.mask_source for p in photos] == ["keyed", "keyed"]
    assert ((photos[0].alpha > 0.5) == want).mean() > 0.99
    assert photos[0].rgb[0, 0].max() < 1e-3  # the background is gone
    # a mask folder wins over alpha
    masks = tmp_path / "masks"
    masks.mkdir()
    for i in range(2):
        m = np.zeros((RES, RES, 3), np.float32)
        m[8:24, 8:24] = 1
        _png(masks / f"k{i}.png", m)
    photos = make_masks(load_images(keyed), masks)
    assert photos[0].mask_source == "masks:k0.png" and (photos[0].alpha > 0.5).sum() == 256


def test_no_mask_names_the_image(tmp_path):
    d = tmp_path / "noisy"
    d.mkdir()
    rng = np.random.default_rng(0)
    for i in range(2):
        _png(d / f"n{i}.png", rng.uniform(size=(RES, RES, 3)).astype(np.float32))
    with pytest.raises(CaptureError, match=r"n0.png: no mask for this view.*not a uniform background"):
        make_masks(load_images(d))


def test_masks_that_do_not_match_the_images_name_the_mask(tmp_path):
    d = _folder(tmp_path, n=2)
    masks = tmp_path / "masks"
    masks.mkdir()
    _png(masks / "v0.png", np.ones((RES, RES, 3), np.float32))
    with pytest.raises(CaptureError, match=f"{masks}: 1 mask file"):
        make_masks(load_images(d), masks)
    _png(masks / "v1.png", np.ones((RES + 2, RES + 2, 3), np.float32))
    with pytest.raises(CaptureError, match=r"v1.png: mask is 34x34, its image v1.png is 32x32"):
        make_masks(load_images(d), masks)


def test_masks_match_photos_by_number_as_in_neus_dtu(tmp_path):
    """NeuS's DTU names photos image/000000.png and masks mask/000.png: matched by their number, photo by photo (as
    the view selection loads them); a number two masks share is no match."""
    d, masks = tmp_path / "image", tmp_path / "mask"
    d.mkdir(), masks.mkdir()
    for i in range(2):
        _png(d / f"{i:06d}.png", np.full((RES, RES, 3), 0.2 + 0.3 * i, np.float32))
        m = np.zeros((RES, RES, 3), np.float32)
        m[4 + 8 * i : 20 + 8 * i, 8:24] = 1.0
        _png(masks / f"{i:03d}.png", m)
    photos = load_images(d)
    for p in photos:
        (one,) = make_masks([p], masks)
        assert one.alpha.sum() == 16 * 16 and one.alpha[4 + 8 * int(p.name), 8] == 1.0, p.name
    _png(masks / "0001.png", np.ones((RES, RES, 3), np.float32))
    with pytest.raises(CaptureError, match=r"no mask named like photo\(s\) \['000001'\]"):
        make_masks([photos[1]], masks)


def test_empty_masks_name_the_file(tmp_path):
    d = _folder(tmp_path, n=2)
    masks = tmp_path / "masks"
    masks.mkdir()
    _png(masks / "v0.png", np.ones((RES, RES, 3), np.float32))
    _png(masks / "v1.png", np.zeros((RES, RES, 3), np.float32))
    with pytest.raises(CaptureError, match=r"v1.png: the mask is empty"):
        make_masks(load_images(d), masks)
    e = tmp_path / "empty_alpha"
    e.mkdir()
    _png(e / "a.png", _disk())
    _png(e / "b.png", _disk(r=0.001))
    with pytest.raises(CaptureError, match=r"b.png: the mask is empty"):
        make_masks(load_images(e))


# -- cameras ------------------------------------------------------------------------------------------------


def _curated_like(tmp, n=4):
    """Views rendered (analytically) as the training rig would: a disk at the centre; frng cameras.json."""
    cams = rig_cameras(n, DIST, FOV, RES)
    d = _folder(tmp, n=n)
    names = sorted(p.stem for p in d.iterdir())
    entries = [
        {"name": nm, "c2w": c.c2w.tolist(), "intrinsics": c.intr.tolist(), "width": RES, "height": RES}
        for nm, c in zip(names, cams)
    ]
    (tmp / "cameras.json").write_text(json.dumps({"cameras": entries}))
    return d, cams


def test_rig_cameras_are_the_papers_rig():
    cams = rig_cameras(6, DIST, FOV, RES)
    eyes = np.array([c.c2w[:3, 3] for c in cams])
    assert np.allclose(np.linalg.norm(eyes, axis=1), DIST)
    az = np.degrees(np.arctan2(eyes[:, 1], eyes[:, 0])) % 360
    el = np.degrees(np.arcsin(eyes[:, 2] / DIST))
    assert np.allclose(az, [0, 90, 180, 270, 45, 225]) and np.allclose(el, [0, 0, 0, 0, 45, 45])
    with pytest.raises(CaptureError, match="6 views; got 7"):
        rig_cameras(7, DIST, FOV, RES)


def test_more_images_than_the_rig_names_the_folder(tmp_path):
    d = _folder(tmp_path, n=7)
    with pytest.raises(CaptureError, match=f"{d}: --rig paper has 6 views; got 7 images"):
        prepare(d, resolution=RES, distance=DIST, fov_deg=FOV, rig="paper")
    _folder(tmp_path, n=11)
    with pytest.raises(CaptureError, match=f"{d}: 11 images; a capture takes at most 10"):
        load_images(d)


def test_training_rig_cameras_are_kept_exactly(tmp_path):
    """Square views at the model's resolution with the training rig's cameras: the crop is the identity."""
    d, cams = _curated_like(tmp_path)
    cap = prepare(d, resolution=RES, distance=DIST, fov_deg=FOV, cameras=tmp_path / "cameras.json")
    assert np.allclose(cap.c2w, np.stack([c.c2w for c in cams]), atol=1e-9)
    assert np.allclose(cap.intr, np.stack([c.intr for c in cams]), atol=1e-9)
    photo = load_images(d)[0]
    assert np.allclose(cap.rgb[0], photo.rgb, atol=1e-6) and np.allclose(cap.alpha[0, ..., 0], photo.alpha)
    rig = prepare(d, resolution=RES, distance=DIST, fov_deg=FOV, rig="paper")
    assert np.allclose(rig.rgb, cap.rgb) and np.allclose(rig.c2w, cap.c2w)


def test_transforms_json_and_opencv_files_normalise_to_the_rig(tmp_path):
    """The same cameras, 2x further away, 4x the pixels and in other conventions, come out as the rig: a known
    world point projects to the same pixel before and after."""
    d, cams = _curated_like(tmp_path)
    big = tmp_path / "big"
    big.mkdir()
    for f in sorted(d.iterdir()):
        img = io.read_png(f)
        _png(big / f.name, np.kron(img, np.ones((4, 4, 1))))
    s, shift = 2.0, np.array([0.3, -0.2, 0.1])
    frames, opencv = [], []
    for f, c in zip(sorted(big.iterdir()), cams):
        c2w = c.c2w.copy()
        c2w[:3, 3] = c2w[:3, 3] * s + shift
        frames.append({"file_path": f"./{f.stem}", "transform_matrix": camera.c2w_to_blender(c2w).tolist()})
        K = np.array([[c.intr[0] * 4, 0, c.intr[2] * 4], [0, c.intr[1] * 4, c.intr[3] * 4], [0, 0, 1]])
        R = c2w[:3, :3].T
        opencv.append({"image": f.name, "K": K.tolist(), "R": R.tolist(), "t": (-R @ c2w[:3, 3]).tolist()})
    (tmp_path / "transforms.json").write_text(json.dumps({"camera_angle_x": math.radians(FOV), "frames": frames}))
    (tmp_path / "opencv.yaml").write_text(json.dumps({"cameras": opencv}))
    for f in ("transforms.json", "opencv.yaml"):
        cap = prepare(big, resolution=RES, distance=DIST, fov_deg=FOV, cameras=tmp_path / f)
        assert np.allclose(cap.c2w, np.stack([c.c2w for c in cams]), atol=1e-6), f
        assert np.allclose(cap.intr, np.stack([c.intr for c in cams]), atol=1e-6), f
        p = torch.tensor([[0.2, -0.1, 0.3]], dtype=torch.float64)
        uv, _ = camera.project(p, torch.tensor(cap.c2w), torch.tensor(cap.intr))
        uv0, _ = camera.project(
            p, torch.tensor(np.stack([c.c2w for c in cams])), torch.tensor(np.stack([c.intr for c in cams]))
        )
        assert torch.allclose(uv, uv0, atol=1e-6)
        assert (np.abs(cap.alpha[..., 0] - (_disk()[..., 3])) > 0.5).mean() < 0.02


def test_cameras_that_do_not_look_at_a_common_centre_name_the_file(tmp_path):
    d, cams = _curated_like(tmp_path)
    entries = json.loads((tmp_path / "cameras.json").read_text())["cameras"]
    turned = np.array(entries[2]["c2w"])
    turned[:3, :3] = turned[:3, :3] @ np.array([[0.0, 0, 1], [0, 1, 0], [-1, 0, 0]])  # 90 deg about its y axis
    entries[2]["c2w"] = turned.tolist()  # looks 90 degrees away
    (tmp_path / "bad.json").write_text(json.dumps({"cameras": entries}))
    with pytest.raises(CaptureError, match=r"bad.json: the camera of v2.png does not look at the common centre"):
        prepare(d, resolution=RES, distance=DIST, fov_deg=FOV, cameras=tmp_path / "bad.json")
    (tmp_path / "few.json").write_text(json.dumps({"cameras": entries[:2]}))
    with pytest.raises(CaptureError, match=r"few.json: no camera for image"):
        prepare(d, resolution=RES, distance=DIST, fov_deg=FOV, cameras=tmp_path / "few.json")


def test_object_framing_crops_around_the_object(tmp_path):
    """Off-centre small objects in wide photos: cropped so the widest silhouette spans the unit sphere's size."""
    d = tmp_path / "wide"
    d.mkdir()
    for i in range(3):
        img = np.zeros((60, 120, 4), np.float32)
        img[20:40, 70 + i : 90 + i] = (0.5, 0.5, 0.5, 1)
        _png(d / f"w{i}.png", img)
    cap = prepare(d, resolution=RES, distance=DIST, fov_deg=FOV, rig="paper")
    assert cap.info["crops"][0]["framing"] == "object"
    fill = math.tan(math.asin(1 / DIST)) / math.tan(math.radians(FOV) / 2)
    ys, xs = np.nonzero(cap.alpha[0, ..., 0] > 0.5)
    assert abs((xs.max() - xs.min() + 1) / RES - fill) < 2.5 / RES
    assert abs((xs.max() + xs.min() + 1) / 2 - RES / 2) <= 1 and abs((ys.max() + ys.min() + 1) / 2 - RES / 2) <= 1


# -- light ----------------------------------------------------------------------------------------------------


def test_light_estimate_recovers_the_irradiance():
    """A Lambertian sphere of known albedo under a smooth light: the fitted light's irradiance over the seen
    normals matches the true one."""
    g = torch.Generator().manual_seed(0)
    n = torch.randn(4000, 3, generator=g, dtype=torch.float64)
    n = n / n.norm(dim=-1, keepdim=True)
    n = n[n[:, 2] > -0.3]
    env = envmap.pixel_directions(16, 32, dtype=torch.float64)
    true = (0.6 + 0.5 * env[..., 2:3].clamp_min(0) + 0.3 * env[..., 0:1].clamp_min(0)).repeat(1, 1, 3)
    true[..., 0] *= 1.2
    E = envmap.sh_irradiance(envmap.sh_project(true), n)
    albedo = torch.tensor([0.5, 0.4, 0.3], dtype=torch.float64).expand_as(n)
    rgb = albedo * E / math.pi
    V = n.shape[0]
    args = (rgb.numpy()[None, None], np.ones((1, 1, V, 1)), albedo.numpy()[None, None], n.numpy()[None, None], 16)
    est, info = estimate_light(*args, colour="fit")
    assert est.shape == (16, 32, 3) and np.isfinite(est).all() and info["pixels"] == V
    E2 = envmap.sh_irradiance(envmap.sh_project(torch.from_numpy(est).double()), n)
    rel = ((E2 - E).abs() / E).mean().item()
    assert rel < 0.08, rel
    # the default, grey world: same luminance, no colour cast; the irradiance's shape is kept
    grey, info = estimate_light(*args)
    assert info["colour"] == "neutral"
    mean = grey.reshape(-1, 3).mean(0)
    assert np.allclose(mean, mean.mean(), rtol=0.02)
    assert abs(envmap.luminance(mean) / envmap.luminance(est.reshape(-1, 3).mean(0)) - 1) < 0.02
    E3 = envmap.sh_irradiance(envmap.sh_project(torch.from_numpy(grey).double()), n)
    assert np.corrcoef(E3[:, 1].numpy(), E[:, 1].numpy())[0, 1] > 0.95


def test_maps_not_2to1_or_not_finite_name_the_file(tmp_path):
    io.write_exr(tmp_path / "square.exr", np.ones((16, 16, 3), np.float32))
    with pytest.raises(CaptureError, match=r"square.exr: equirect maps must be 2:1"):
        read_light(tmp_path / "square.exr")
    bad = np.ones((16, 32, 3), np.float32)
    bad[3, 4, 1] = np.nan
    io.write_exr(tmp_path / "nan.exr", bad)
    with pytest.raises(CaptureError, match=r"nan.exr: environment map contains NaN"):
        read_light(tmp_path / "nan.exr")


# -- assets: render side ---------------------------------------------------------------------------------------


def synthetic_asset(folder: Path, version_bump: bool = False, textured: bool = False) -> Path:
    """A small neural asset: a ball of Gaussians with a cosine decoder (normal + diffuse in the features);
    ``textured``: each Gaussian its own random albedo (else one colour)."""
    from frng.apps.asset import render_settings, save_asset
    from frng.gaussians import Gaussians
    from frng.render import RasterConfig
    from frng.render.shading import NeuralDecoder, ShadingConfig

    g = torch.Generator().manual_seed(0)
    N, C = 400, 10
    d = torch.randn(N, 3, generator=g)
    d = d / d.norm(dim=-1, keepdim=True)
    feats = torch.zeros(N, C)
    feats[:, :3] = d
    feats[:, 3:6] = torch.tensor([0.6, 0.3, 0.2]) / math.pi
    if textured:
        feats[:, 3:6] = (0.1 + 0.8 * torch.rand(N, 3, generator=g)) / math.pi
    gauss = Gaussians(
        0.8 * d, torch.tensor([[1.0, 0, 0, 0]]).repeat(N, 1), torch.full((N, 3), 0.12), torch.full((N,), 0.9), feats
    )
    dec = NeuralDecoder(C, 16, 2, 0, cosine=True, attenuation=True)
    meta = {
        "object_id": "ball",
        "decoder": {
            "width": 16,
            "depth": 2,
            "input_encoding": "raw",
            "dir_freqs": 0,
            "feature_dim": C,
            "cosine": True,
            "attenuation": True,
            "head": "neural",
            "specular": True,
        },
        **render_settings(RasterConfig.from_dict({}), ShadingConfig.from_dict({"spp_infer": 8}), 8),
        "rig": {"camera_distance": DIST, "fov_deg": FOV, "resolution": RES},
    }
    save_asset(folder, gauss, feats, dec.state_dict(), meta)
    if version_bump:
        j = json.loads((folder / "asset.json").read_text())
        j["version"] = 99
        (folder / "asset.json").write_text(json.dumps(j))
    return folder


def _frng(*args, cwd=None):
    return subprocess.run(
        [sys.executable, "-m", "frng", *map(str, args)], cwd=cwd or ROOT, capture_output=True, text=True, timeout=300
    )


def test_render_asset_views_and_turntable(tmp_path):
    asset = synthetic_asset(tmp_path / "ball")
    env = tmp_path / "sky.exr"
    sky = np.ones((16, 32, 3), np.float32) * 0.3
    sky[:4] = 3.0
    envmap.write(env, sky)
    r = _frng("render-asset", asset, "--env", env, "--turntable", 4, "--out", tmp_path / "turn")
    assert r.returncode == 0, r.stdout + r.stderr
    out = tmp_path / "turn"
    for i in range(4):
        img = io.read_rgba(out / f"turn_{i:03d}.exr", require_alpha=True)
        assert img.shape == (RES, RES, 4) and img[..., 3].max() > 0.9 and np.isfinite(img).all()
        assert (out / f"turn_{i:03d}.png").exists()
    import imageio.v3 as iio

    frames = iio.imread(out / "turntable.gif", index=None)
    assert frames.shape[0] == 4
    # lit from above: the top of the ball is brighter than the bottom
    img = io.read_rgba(out / "turn_000.exr")
    ys, _ = np.nonzero(img[..., 3] > 0.5)
    top, bot = img[ys.min() : ys.min() + 3, :, 0].sum(), img[ys.max() - 2 : ys.max() + 1, :, 0].sum()
    assert top > bot
    # a camera file, in the asset's world
    cams = {"cameras": json.loads((out / "cameras.json").read_text())["cameras"][:2]}
    (tmp_path / "cams.json").write_text(json.dumps(cams))
    r = _frng("render-asset", asset, "--env", env, "--cameras", tmp_path / "cams.json", "--out", tmp_path / "two")
    assert r.returncode == 0, r.stdout + r.stderr
    assert np.allclose(io.read_rgba(tmp_path / "two" / "turn_001.exr"), io.read_rgba(out / "turn_001.exr"))


def test_render_asset_bad_input_is_one_line_naming_the_file(tmp_path):
    asset = synthetic_asset(tmp_path / "ball")
    envmap.write(tmp_path / "ok.exr", np.ones((8, 16, 3), np.float32))
    io.write_exr(tmp_path / "square.exr", np.ones((16, 16, 3), np.float32))
    r = _frng("render-asset", asset, "--env", tmp_path / "square.exr", "--out", tmp_path / "o")
    assert r.returncode == 2 and "square.exr: equirect maps must be 2:1" in r.stdout
    assert len(r.stdout.strip().splitlines()) == 1 and "Traceback" not in r.stderr
    old = synthetic_asset(tmp_path / "v99", version_bump=True)
    r = _frng("render-asset", old, "--env", tmp_path / "ok.exr", "--out", tmp_path / "o")
    assert r.returncode == 2 and f"{old / 'asset.json'}: field 'version' is 99" in r.stdout


def test_reconstruct_bad_input_is_one_line_naming_the_file(tmp_path):
    d = _folder(tmp_path, n=1)
    r = _frng("reconstruct", "--images", d, "--out", tmp_path / "a", "--config", ROOT / "config" / "smoke.yaml")
    assert r.returncode == 2 and f"{d}: 1 image(s)" in r.stdout and "Traceback" not in r.stderr
    assert len(r.stdout.strip().splitlines()) == 1 and not (tmp_path / "a").exists()
    d = _folder(tmp_path, n=3)
    io.write_exr(tmp_path / "square.exr", np.ones((16, 16, 3), np.float32))
    r = _frng(
        "reconstruct",
        "--images",
        d,
        "--out",
        tmp_path / "a",
        "--light",
        tmp_path / "square.exr",
        "--config",
        ROOT / "config" / "smoke.yaml",
    )
    assert r.returncode == 2 and "square.exr: equirect maps must be 2:1" in r.stdout
    r = _frng("reconstruct", "--images", d, "--out", tmp_path / "a", "--model", tmp_path / "m" / "full" / "model.pt")
    assert r.returncode == 2 and "config.yaml: no recorded config beside the model" in r.stdout


def test_reconstruct_camera_file_for_other_images_bad_distortion_and_no_held_out_views_are_one_line(tmp_path):
    """Through the command line, before any model is read: exit 2, one line naming the file (and the field), no
    traceback, nothing written."""
    d, _ = _curated_like(tmp_path)
    entries = json.loads((tmp_path / "cameras.json").read_text())["cameras"]
    other = [{**e, "name": f"IMG_{i:04d}.JPG"} for i, e in enumerate(entries)]
    (tmp_path / "other.json").write_text(json.dumps({"cameras": other}))
    (tmp_path / "dist.json").write_text(json.dumps({"cameras": [{**e, "dist": [0.0, 0.0, 0.5, 0.0]} for e in entries]}))
    config = ROOT / "config" / "smoke.yaml"
    cases = [
        (["--cameras", tmp_path / "other.json"], ["other.json: its 4 cameras name none of the 4 photos", "IMG_0000"]),
        (["--cameras", tmp_path / "dist.json"], ["dist.json: camera of v0", "p1=0.5", "tangential"]),
        (["--measure-heldout"], [f"{d}: --measure-heldout", "--cameras or --sfm"]),
        (
            ["--cameras", tmp_path / "cameras.json", "--measure-heldout"],
            [f"{d}: --measure-heldout: no photo is held out"],
        ),
    ]
    for extra, words in cases:
        r = _frng("reconstruct", "--images", d, "--out", tmp_path / "a", "--config", config, *extra)
        assert r.returncode == 2 and "Traceback" not in r.stderr, r.stdout + r.stderr
        assert len(r.stdout.strip().splitlines()) == 1 and all(w in r.stdout for w in words), (words, r.stdout)
        assert not (tmp_path / "a").exists() and not any(p.name.startswith(".tmp") for p in tmp_path.iterdir())
