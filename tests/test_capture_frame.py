"""Upright, centred captures and view selection (frng.apps.capture_frame): a capture turned by a random rotation (and
moved and scaled) gives the same asset frame (up to the azimuth, which stays the user's); an upright world keeps its
frame exactly; the views chosen among more photos cover the training rig's directions and prefer sharp photos whose
object is whole; the others are held out with their cameras. Synthetic, no models, seconds."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
from scipy import ndimage
from scipy.spatial.transform import Rotation

from frng import camera, io
from frng.apps.capture import CaptureError, load_images, prepare, rig_cameras
from frng.apps.capture_frame import (
    camera_up,
    choose_views,
    light_to_asset,
    photo_quality,
    points_centre,
    quality_penalty,
    rig_directions,
    rotate_envmap,
    similarity,
    to_asset,
    upright_rotation,
)
from frng.render import envmap

RES, DIST, FOV = 32, 4.0, 30.0


def _disk(res=RES, r=0.3, cx=0.5, cy=0.5, texture=None):
    yy, xx = np.mgrid[0:res, 0:res] + 0.5
    inside = ((xx / res - cx) ** 2 + (yy / res - cy) ** 2) < r * r
    img = np.zeros((res, res, 4), np.float32)
    img[inside, :3] = (0.8, 0.3, 0.2)
    if texture is not None:
        img[..., :3] *= texture[..., None]
    img[..., 3] = inside
    return img


def _folder(tmp: Path, names, res=RES) -> Path:
    d = tmp / "images"
    d.mkdir(exist_ok=True)
    for n in names:
        io.write_png(d / f"{n}.png", _disk(res))
    return d


def _write_cams(path: Path, names, c2ws, res=RES, fov=FOV, **extra):
    intr = camera.intrinsics_from_fov(fov, res, res)
    entries = [
        {"name": n, "c2w": np.asarray(c).tolist(), "intrinsics": intr.tolist(), "width": res, "height": res}
        for n, c in zip(names, c2ws)
    ]
    path.write_text(json.dumps({"cameras": entries, **extra}))
    return path


def _moved(c2ws, R, t, s):
    """The same cameras in another world: x' = s R x + t."""
    out = []
    for c in c2ws:
        c = np.array(c)
        c[:3, :3] = R @ c[:3, :3]
        c[:3, 3] = s * R @ c[:3, 3] + t
        out.append(c)
    return out


# -- up, rotation ------------------------------------------------------------------------------------------------


def test_an_upright_world_keeps_its_frame_exactly():
    c2ws = np.stack([c.c2w for c in rig_cameras(6, DIST, FOV, RES)])
    up, source = camera_up(c2ws)
    assert np.array_equal(upright_rotation(up), np.eye(3)) and "right axes" in source
    # two cameras facing each other: their right axes are parallel, the mean up vector decides
    up, source = camera_up(c2ws[[0, 2]])
    assert np.allclose(up, [0, 0, 1]) and "mean up" in source
    assert np.allclose(upright_rotation([0, 0, -1]) @ [0, 0, -1], [0, 0, 1])


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_a_rotated_capture_gives_the_same_asset_frame(tmp_path, seed):
    """The rig's cameras, and the same cameras turned by a random rotation, moved and scaled (and looking down at
    the object from 20-50 deg, not only at the horizon): the asset cameras are the same up to a turn about Z."""
    rng = np.random.default_rng(seed)
    names = [f"v{i}" for i in range(6)]
    c2ws = [
        camera.look_at(camera.spherical_to_cartesian(az, el, DIST))
        for az, el in zip(rng.uniform(0, 360, 6), [0, 20, 45, 30, 0, 50])
    ]
    images = _folder(tmp_path, names)
    a = prepare(
        images, resolution=RES, distance=DIST, fov_deg=FOV, cameras=_write_cams(tmp_path / "a.json", names, c2ws)
    )
    R = Rotation.random(random_state=seed).as_matrix()
    moved = _moved(c2ws, R, rng.normal(size=3) * 5, 2.7)
    b = prepare(
        images, resolution=RES, distance=DIST, fov_deg=FOV, cameras=_write_cams(tmp_path / "b.json", names, moved)
    )
    assert np.allclose(a.c2w, np.stack(c2ws), atol=1e-9)  # upright already: unchanged
    Rz = b.c2w[0, :3, :3] @ a.c2w[0, :3, :3].T
    assert np.allclose(Rz[2], [0, 0, 1], atol=1e-6) and np.allclose(Rz[:, 2], [0, 0, 1], atol=1e-6)
    for ca, cb in zip(a.c2w, b.c2w):
        assert np.allclose(cb[:3, :3], Rz @ ca[:3, :3], atol=1e-6)
        assert np.allclose(cb[:3, 3], Rz @ ca[:3, 3], atol=1e-6)
    assert np.allclose(a.intr, b.intr, atol=1e-6) and np.allclose(a.rgb, b.rgb, atol=1e-5)
    # the recorded transform maps the user's cameras to the asset's
    M = np.array(b.info["world_to_asset"])
    for user, asset in zip(moved, b.c2w):
        assert np.allclose(to_asset(user, M), asset, atol=1e-6)
    assert "right axes" in b.info["up"]["source"]


def test_the_files_up_is_used_when_given(tmp_path):
    names = [f"v{i}" for i in range(4)]
    c2ws = [c.c2w for c in rig_cameras(4, DIST, FOV, RES)]
    R = Rotation.from_euler("x", 90, degrees=True).as_matrix()  # Z up -> -Y up
    images = _folder(tmp_path, names)
    path = _write_cams(tmp_path / "c.json", names, _moved(c2ws, R, np.zeros(3), 1.0), up=[0, -1, 0])
    cap = prepare(images, resolution=RES, distance=DIST, fov_deg=FOV, cameras=path)
    assert cap.info["up"]["source"] == "the camera file's up"
    assert np.allclose(cap.c2w[:, :3, 3], np.stack(c2ws)[:, :3, 3], atol=1e-6)


def test_similarity_and_light_to_asset():
    R = upright_rotation([1.0, 0.0, 0.0])
    M = similarity(R, np.array([0.1, 0.2, 0.3]), 2.0)
    assert np.allclose(M[:3, :3] @ [1, 0, 0], [0, 0, 2])
    env = np.random.default_rng(0).uniform(size=(16, 32, 3)).astype(np.float32)
    assert light_to_asset(env, similarity(np.eye(3), np.zeros(3), 3.0)) is env


def test_rotate_envmap_turns_the_light():
    H, Wd = 32, 64
    env = np.full((H, Wd, 3), 0.01, np.float32)
    env[4:7, 20:24] = 10.0  # a bright patch
    # about Z: the same as envmap.rotate_z
    Rz = Rotation.from_euler("z", 37, degrees=True).as_matrix()
    assert np.allclose(rotate_envmap(env, Rz)[2:-2], envmap.rotate_z(env, 37.0)[2:-2], atol=1e-4)
    # any rotation: the patch's direction d arrives from R d
    R = Rotation.from_euler("xyz", [30, -50, 20], degrees=True).as_matrix()
    import torch

    dirs = envmap.pixel_directions(H, Wd, dtype=torch.float64).numpy()
    lum = env[..., 0]
    d = (dirs * lum[..., None]).sum((0, 1))
    turned = rotate_envmap(env, R)[..., 0]
    d2 = (dirs * turned[..., None]).sum((0, 1))
    cos = (R @ d) @ d2 / np.linalg.norm(d) / np.linalg.norm(d2)
    assert cos > 0.99


def test_points_centre_keeps_the_points_inside_the_masks():
    cams = rig_cameras(4, DIST, FOV, RES)
    alphas = [_disk()[..., 3] for _ in cams]
    rng = np.random.default_rng(0)
    obj = rng.normal(size=(50, 3))
    obj = 0.15 * obj / np.linalg.norm(obj, axis=1, keepdims=True) + [0.0, 0.05, 0.0]
    wall = rng.uniform(-1, 1, size=(200, 3)) * [0.1, 3, 3] + [-3, 0, 0]  # behind the object from one side
    c, n = points_centre(np.concatenate([obj, wall]), cams, alphas)
    assert n >= 45 and np.linalg.norm(c - obj.mean(0)) < 0.02
    c, n = points_centre(wall, cams, alphas)
    assert c is None


# -- view selection ----------------------------------------------------------------------------------------------


def _sphere_dirs():
    out = []
    for el in (0, 20, 45, 70):
        for az in range(0, 360, 30):
            out.append(camera.spherical_to_cartesian(az + 7, el, 1.0))
    return np.stack(out)


def test_chosen_views_cover_the_rig():
    dirs = _sphere_dirs()
    order = np.random.default_rng(0).permutation(len(dirs))
    idx, cover = choose_views(dirs[order], np.zeros(len(dirs)), 6)
    chosen = dirs[order][idx]
    el = np.degrees(np.arcsin(chosen[:, 2]))
    az = np.degrees(np.arctan2(chosen[:, 1], chosen[:, 0])) % 360
    assert np.allclose(el, [0, 0, 0, 0, 45, 45])
    assert np.allclose(np.diff(az[:4]) % 360, 90) and np.isclose((az[5] - az[4]) % 360, 180)
    assert cover["worst_deg"] < 11  # the 45 deg ring has no photo at the rig's azimuth + 45: 15 deg of azimuth off
    # more views than the rig: the rest farthest first
    idx8, _ = choose_views(dirs[order], np.zeros(len(dirs)), 8)
    d8 = dirs[order][idx8]
    gaps = np.degrees(np.arccos(np.clip(d8 @ d8.T, -1, 1))) + 1000 * np.eye(8)
    assert idx8[:6] == idx and len(set(idx8)) == 8 and gaps[6:].min() >= 30
    assert len(choose_views(dirs, np.zeros(len(dirs)), 3)[0]) == 3


def test_selection_prefers_sharp_photos_of_the_whole_object():
    rng = np.random.default_rng(0)
    texture = 0.5 + 0.5 * rng.uniform(size=(128, 128))
    sharp = _disk(128, texture=texture)
    blurred = sharp.copy()
    blurred[..., :3] = ndimage.gaussian_filter(sharp[..., :3], (2.5, 2.5, 0))
    cut = _disk(128, cx=0.12, texture=texture)  # runs off the left border
    small = _disk(128, r=0.1, texture=texture[:128, :128])
    q = [photo_quality(i[..., :3] * i[..., 3:], i[..., 3]) for i in (sharp, blurred, cut, small)]
    assert q[0]["sharpness"] > 3 * q[1]["sharpness"] and q[2]["cut"] and not q[0]["cut"]
    pen = quality_penalty(q + [q[0]] * 4)
    assert pen[0] < 0.05 and pen[1] > 0.2 and pen[2] > 1.0 and pen[3] > 0.2
    # each rig direction offered twice: a flawed photo right on it and a good one 10 deg off
    base = rig_directions()
    tilt = Rotation.from_euler("z", 10, degrees=True).as_matrix()
    dirs = np.concatenate([base, base @ tilt.T])
    flawed = [1, 2, 3, 1, 2, 3]
    qual = [q[f] for f in flawed] + [q[0]] * 6
    idx, _ = choose_views(dirs, quality_penalty(qual), 6)
    assert sorted(idx) == list(range(6, 12))


def _ring(n):
    """``n`` cameras around the object: elevation 0 and 45 alternating, azimuths evenly spread."""
    return [
        camera.look_at(camera.spherical_to_cartesian(i * 360.0 / n, 0.0 if i % 2 == 0 else 45.0, DIST))
        for i in range(n)
    ]


def test_more_photos_than_views_are_chosen_and_the_rest_held_out(tmp_path):
    names = [f"p{i:02d}" for i in range(14)]
    images = _folder(tmp_path, names)
    c2ws = _ring(14)
    cams = _write_cams(tmp_path / "c.json", names, c2ws)
    with pytest.raises(CaptureError, match="14 images; a capture takes at most 10 views"):
        prepare(images, resolution=RES, distance=DIST, fov_deg=FOV, rig="paper")
    cap = prepare(images, resolution=RES, distance=DIST, fov_deg=FOV, cameras=cams)
    sel = cap.info["selection"]
    assert len(cap.names) == 6 and cap.names == sel["chosen"] and len(sel["held_out"]) == 8
    assert sorted(sel["chosen"] + sel["held_out"]) == names
    assert "6 of 14 photos chosen" in sel["summary"] and "\n" not in sel["summary"]
    el = np.degrees(np.arcsin(cap.c2w[:, 2, 3] / DIST))
    assert (np.abs(el) < 1).sum() == 4 and (np.abs(el - 45) < 1).sum() == 2
    M = np.array(cap.info["world_to_asset"])
    held = {h["name"]: h for h in cap.info["held_out_cameras"]}
    assert sorted(held) == sorted(sel["held_out"])
    for n, c in zip(names, c2ws):
        if n in held:
            assert np.allclose(np.array(held[n]["c2w"]), to_asset(c, M), atol=1e-9)
            assert held[n]["width"] == RES
    # --select among 10 or fewer; a count the model does not take, or more than the photos, is an error
    small = tmp_path / "few"
    small.mkdir()
    for n in names[:8]:
        (small / f"{n}.png").write_bytes((images / f"{n}.png").read_bytes())
    cap = prepare(small, resolution=RES, distance=DIST, fov_deg=FOV, cameras=cams, select=3)
    assert len(cap.names) == 3
    with pytest.raises(CaptureError, match="--select 12: the model takes 2-10 views"):
        prepare(small, resolution=RES, distance=DIST, fov_deg=FOV, cameras=cams, select=12)
    with pytest.raises(CaptureError, match="--select 9, but the folder holds 8 images"):
        prepare(small, resolution=RES, distance=DIST, fov_deg=FOV, cameras=cams, select=9)
    with pytest.raises(CaptureError, match="--select 3: views are chosen among a folder of photos with --cameras"):
        prepare(small, resolution=RES, distance=DIST, fov_deg=FOV, rig="paper", select=3)
    assert len(load_images(small, only=["p00", "p03"])) == 2


def test_selection_skips_photos_whose_object_is_cut_off(tmp_path):
    names = [f"p{i:02d}" for i in range(12)]
    images = _folder(tmp_path, names)
    c2ws = _ring(12)
    # p00's twin p12 sits 5 deg away but its object runs off the frame
    io.write_png(images / "p12.png", _disk(cx=0.1))
    names.append("p12")
    c2ws.append(camera.look_at(camera.spherical_to_cartesian(5.0, 0.0, DIST)))
    cap = prepare(
        images, resolution=RES, distance=DIST, fov_deg=FOV, cameras=_write_cams(tmp_path / "c.json", names, c2ws)
    )
    assert "p12" not in cap.names and "p12" in cap.info["selection"]["held_out"]
    assert cap.info["selection"]["scores"]["p12"]["cut"] is True
    assert math.isclose(cap.info["selection"]["scores"]["p00"]["penalty"], 0.0, abs_tol=1e-9)


def test_photos_without_a_mask_are_left_out_when_enough_remain(tmp_path):
    """A photo whose mask cannot be made (no alpha, a noisy background GrabCut refuses) is left out of the choice
    and named, with its reason; when too few photos remain, one error says how many and why."""
    names = [f"p{i:02d}" for i in range(12)]
    images = _folder(tmp_path, names)
    rng = np.random.default_rng(0)
    for n in ("p03", "p07"):  # no alpha, texture everywhere: no mask to be had
        io.write_png(images / f"{n}.png", rng.uniform(size=(RES, RES, 3)).astype(np.float32))
    cams = _write_cams(tmp_path / "c.json", names, _ring(12))
    cap = prepare(images, resolution=RES, distance=DIST, fov_deg=FOV, cameras=cams)
    sel = cap.info["selection"]
    assert sorted(sel["no_mask"]) == ["p03", "p07"] and "no mask for this view" in sel["no_mask"]["p03"]
    assert not {"p03", "p07"} & set(sel["chosen"] + sel["held_out"]) and len(sel["chosen"]) == 6
    assert sel["summary"].endswith("2 left out, no mask: p03, p07")
    io.write_png(images / "p10.png", rng.uniform(size=(RES, RES, 3)).astype(np.float32))
    with pytest.raises(CaptureError, match=r"3 of 12 photos have no mask, 9 left for 10 views; the first: .*p03"):
        prepare(images, resolution=RES, distance=DIST, fov_deg=FOV, cameras=cams, select=10)
