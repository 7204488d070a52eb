"""Camera files `frng reconstruct --cameras` reads (frng.apps.camera_formats): COLMAP text and binary, LLFF
poses_bounds.npy, IDR / NeuS cameras_sphere.npz, transforms.json and OpenCV files with their distortion. Synthetic
cameras written in every format: a known world point projects to the same pixel from each; a distorted synthetic grid
is straightened; bad input is one line naming the file and the field. No models, seconds."""

from __future__ import annotations

import json
import math
import struct
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from frng import camera, io
from frng.apps.camera_formats import (
    COLMAP_BY_NAME,
    Distortion,
    read_camera_set,
    undistort_image,
)
from frng.apps.capture import CaptureError, prepare, read_cameras, rig_cameras

W, H = 64, 48
X = np.array([0.1, -0.2, 0.15])  # the known world point


def _scene(n=5, seed=0, centred=False):
    """``n`` OpenCV cameras around the origin: names, c2w, intrinsics (fx, fy, cx, cy) of a W x H image."""
    rng = np.random.default_rng(seed)
    names, c2ws, intrs = [], [], []
    for i in range(n):
        eye = camera.spherical_to_cartesian(rng.uniform(0, 360), rng.uniform(-10, 50), rng.uniform(2.5, 4.0))
        c2ws.append(camera.look_at(eye, rng.normal(0, 0.05, 3)))
        f = rng.uniform(40, 70)
        if centred:
            intrs.append(np.array([f, f, W / 2, H / 2]))
        else:
            intrs.append(
                np.array([f, f * rng.uniform(0.95, 1.05), W / 2 + rng.uniform(-3, 3), H / 2 + rng.uniform(-3, 3)])
            )
        names.append(f"img_{i:02d}")
    return names, c2ws, intrs


def _project(c2w, intr, p, dist: Distortion | None = None):
    q = np.linalg.inv(c2w) @ np.append(p, 1.0)
    x, y = q[0] / q[2], q[1] / q[2]
    if dist is not None:
        x, y = dist.distort(np.array(x), np.array(y))
    return np.array([intr[0] * x + intr[2], intr[1] * y + intr[3]])


def _w2c(c2w):
    R = c2w[:3, :3].T
    return R, -R @ c2w[:3, 3]


def _quat(R):
    x, y, z, w = Rotation.from_matrix(R).as_quat()
    return [w, x, y, z]


def write_colmap_text(folder: Path, names, c2ws, intrs, points=None, model="PINHOLE", extra=()):
    folder.mkdir(parents=True, exist_ok=True)
    cams, imgs = ["# Camera list"], ["# Image list"]
    for i, (n, c2w, k) in enumerate(zip(names, c2ws, intrs)):
        params = list(k) if model != "SIMPLE_PINHOLE" else [k[0], k[2], k[3]]
        cams.append(" ".join(str(v) for v in [i + 1, model, W, H, *params, *extra]))
        R, t = _w2c(c2w)
        imgs.append(" ".join(str(v) for v in [i + 1, *_quat(R), *t, i + 1, f"sub/{n}.jpg"]))
        imgs.append("")  # its (here empty) 2D points
    (folder / "cameras.txt").write_text("\n".join(cams) + "\n")
    (folder / "images.txt").write_text("\n".join(imgs) + "\n")
    if points is not None:
        (folder / "points3D.txt").write_text(
            "\n".join(f"{i + 1} {p[0]} {p[1]} {p[2]} 128 128 128 0.5 1 0" for i, p in enumerate(points)) + "\n"
        )
    return folder


def write_colmap_binary(folder: Path, names, c2ws, intrs, points=None, model="PINHOLE", extra=()):
    folder.mkdir(parents=True, exist_ok=True)
    mid = COLMAP_BY_NAME[model][0]
    b = struct.pack("<Q", len(names))
    for i, k in enumerate(intrs):
        b += struct.pack("<iiQQ", i + 1, mid, W, H) + struct.pack(f"<{4 + len(extra)}d", *k, *extra)
    (folder / "cameras.bin").write_bytes(b)
    b = struct.pack("<Q", len(names))
    for i, (n, c2w) in enumerate(zip(names, c2ws)):
        R, t = _w2c(c2w)
        b += struct.pack("<i4d3di", i + 1, *_quat(R), *t, i + 1) + f"{n}.png".encode() + b"\0"
        b += struct.pack("<Q", 2) + struct.pack("<ddqddq", 1.0, 2.0, -1, 3.0, 4.0, 1)
    (folder / "images.bin").write_bytes(b)
    if points is not None:
        b = struct.pack("<Q", len(points))
        for i, p in enumerate(points):
            b += struct.pack("<Q3d3Bd", i + 1, *p, 1, 2, 3, 0.5) + struct.pack("<Q", 1) + struct.pack("<ii", 1, 0)
        (folder / "points3D.bin").write_bytes(b)
    return folder


def write_llff(path: Path, c2ws, intrs):
    rows = []
    for c2w, k in zip(c2ws, intrs):
        P = np.zeros((3, 5))
        P[:, 0], P[:, 1], P[:, 2], P[:, 3] = c2w[:3, 1], c2w[:3, 0], -c2w[:3, 2], c2w[:3, 3]
        P[:, 4] = [H, W, k[0]]
        rows.append(np.concatenate([P.reshape(-1), [0.5, 10.0]]))
    np.save(path, np.array(rows))
    return path


def write_idr(path: Path, c2ws, intrs, centre, radius, scales=None):
    arrays = {}
    S = np.eye(4)
    S[:3, :3] *= radius
    S[:3, 3] = centre
    for i, (c2w, k) in enumerate(zip(c2ws, intrs)):
        K = np.eye(4)
        K[0, 0], K[1, 1], K[0, 2], K[1, 2] = k
        world_mat = K @ np.linalg.inv(c2w) * (1.0 if scales is None else scales[i])
        arrays[f"world_mat_{i}"] = world_mat
        arrays[f"scale_mat_{i}"] = S
        # NeuS's archives (DTU, BlendedMVS) hold these too: keys that start like world_mat_ but are not numbered
        arrays[f"world_mat_inv_{i}"] = np.linalg.inv(world_mat)
        arrays[f"scale_mat_inv_{i}"] = np.linalg.inv(S)
        arrays[f"camera_mat_{i}"] = K
    np.savez(path, **arrays)
    return path


def _check_projects(cset, names, c2ws, intrs, point, expect_point=None):
    got = cset.assign(names)
    for n, c2w, k in zip(names, c2ws, intrs):
        uv0 = _project(c2w, k, X)
        uv = _project(got[n].c2w, got[n].intr, point)
        assert np.allclose(uv, uv0, atol=1e-6), (cset.format, n, uv, uv0)


@pytest.mark.parametrize(
    "fmt", ["colmap-text", "colmap-binary", "colmap-sparse0", "llff", "idr", "transforms", "opencv"]
)
def test_every_format_projects_a_known_point_to_the_same_pixel(tmp_path, fmt):
    names, c2ws, intrs = _scene(centred=fmt == "llff")
    point = X
    if fmt == "colmap-text":
        path = write_colmap_text(tmp_path / "m", names, c2ws, intrs) / "images.txt"
    elif fmt == "colmap-binary":
        path = write_colmap_binary(tmp_path / "m", names, c2ws, intrs)
    elif fmt == "colmap-sparse0":
        write_colmap_text(tmp_path / "scene" / "sparse" / "0", names, c2ws, intrs)
        path = tmp_path / "scene"
    elif fmt == "llff":
        path = write_llff(tmp_path / "poses_bounds.npy", c2ws, intrs)
    elif fmt == "idr":
        centre, radius = np.array([0.3, -0.1, 0.2]), 1.7
        scales = [1.0, -1.7, 2.5, 0.3, -0.9]  # P is defined up to a scale, whatever its sign
        path = write_idr(tmp_path / "cameras_sphere.npz", c2ws, intrs, centre, radius, scales)
        point = (X - centre) / radius  # the normalised frame: the object's unit sphere
    elif fmt == "transforms":
        frames = [
            {"file_path": f"images/{n}.png", "transform_matrix": camera.c2w_to_blender(c).tolist(), "fl_x": k[0],
             "fl_y": k[1], "cx": k[2], "cy": k[3], "w": W, "h": H}
            for n, c, k in zip(names, c2ws, intrs)
        ]  # fmt: skip
        path = tmp_path / "transforms.json"
        path.write_text(json.dumps({"frames": frames}))
    else:
        entries = []
        for n, c, k in zip(names, c2ws, intrs):
            R, t = _w2c(c)
            K = [[k[0], 0, k[2]], [0, k[1], k[3]], [0, 0, 1]]
            entries.append({"image": f"{n}.jpg", "K": K, "R": R.tolist(), "t": t.tolist()})
        path = tmp_path / "opencv.json"
        path.write_text(json.dumps({"cameras": entries}))
    cset = read_camera_set(path, {n: (W, H) for n in names}, fallback=read_cameras)
    assert len(cset.cams) == len(names)
    _check_projects(cset, names, c2ws, intrs, point)
    if fmt == "idr":
        assert np.allclose(cset.centre, 0) and "scale_mat" in cset.centre_source


@pytest.mark.parametrize(
    "model,params,expect",
    [
        ("SIMPLE_RADIAL", [55.0, 31.0, 23.0, -0.1], ("opencv", (-0.1, 0, 0, 0, 0, 0, 0, 0))),
        ("RADIAL", [55.0, 31.0, 23.0, -0.1, 0.02], ("opencv", (-0.1, 0.02, 0, 0, 0, 0, 0, 0))),
        (
            "OPENCV",
            [55.0, 54.0, 31.0, 23.0, -0.1, 0.02, 0.001, -0.002],
            ("opencv", (-0.1, 0.02, 0.001, -0.002, 0, 0, 0, 0)),
        ),
        (
            "FULL_OPENCV",
            [55.0, 54.0, 31.0, 23.0, -0.1, 0.02, 0.001, -0.002, 0.003, 0.01, 0.0, 0.0],
            ("opencv", (-0.1, 0.02, 0.001, -0.002, 0.003, 0.01, 0.0, 0.0)),
        ),
        ("OPENCV_FISHEYE", [55.0, 54.0, 31.0, 23.0, 0.05, -0.01, 0.002, 0.0], ("fisheye", (0.05, -0.01, 0.002, 0.0))),
        ("SIMPLE_PINHOLE", [55.0, 31.0, 23.0], None),
    ],
)
def test_colmap_camera_models_and_their_distortion(tmp_path, model, params, expect):
    """Each COLMAP model's parameters: the point projects (through the distortion) where COLMAP's own formula puts
    it (written out here: radial + tangential, or the equidistant fisheye)."""
    names, c2ws, _ = _scene(n=2)
    folder = tmp_path / "m"
    folder.mkdir()
    (folder / "cameras.txt").write_text(f"1 {model} {W} {H} {' '.join(map(str, params))}\n")
    lines = []
    for i, (n, c2w) in enumerate(zip(names, c2ws)):
        R, t = _w2c(c2w)
        lines += [" ".join(str(v) for v in [i + 1, *_quat(R), *t, 1, f"{n}.png"]), ""]
    (folder / "images.txt").write_text("\n".join(lines))
    cset = read_camera_set(folder)
    cam = dict(cset.cams)[names[0]]
    d = cam.distortion
    assert (None if d is None else (d.model, d.params)) == (
        None if expect is None else (expect[0], tuple(map(float, expect[1])))
    )
    q = np.linalg.inv(c2ws[0]) @ np.append(X, 1.0)
    u, v = q[0] / q[2], q[1] / q[2]
    if expect is not None and expect[0] == "fisheye":
        k1, k2, k3, k4 = expect[1]
        r = math.hypot(u, v)
        th = math.atan(r)
        thd = th * (1 + k1 * th**2 + k2 * th**4 + k3 * th**6 + k4 * th**8)
        u, v = u * thd / r, v * thd / r
    elif expect is not None:  # COLMAP's OpenCVCameraModel / FullOpenCVCameraModel
        k1, k2, p1, p2, k3, k4, k5, k6 = expect[1]
        r2 = u * u + v * v
        radial = (1 + k1 * r2 + k2 * r2**2 + k3 * r2**3) / (1 + k4 * r2 + k5 * r2**2 + k6 * r2**3)
        u, v = u * radial + 2 * p1 * u * v + p2 * (r2 + 2 * u * u), v * radial + 2 * p2 * u * v + p1 * (r2 + 2 * v * v)
    fx, fy, cx, cy = cam.intr
    assert np.allclose(_project(cam.c2w, cam.intr, X, d), [fx * u + cx, fy * v + cy], atol=1e-9)


def test_binary_and_text_models_agree_and_carry_the_points(tmp_path):
    names, c2ws, intrs = _scene()
    pts = np.random.default_rng(1).normal(size=(30, 3))
    extra = (-0.05, 0.01, 0.0005, -0.0003)
    a = read_camera_set(write_colmap_text(tmp_path / "t", names, c2ws, intrs, pts, "OPENCV", extra))
    b = read_camera_set(write_colmap_binary(tmp_path / "b", names, c2ws, intrs, pts, "OPENCV", extra))
    assert a.format == b.format == "COLMAP" and [n for n, _ in a.cams] == [n for n, _ in b.cams] == names
    for (_, ca), (_, cb) in zip(a.cams, b.cams):
        assert np.allclose(ca.c2w, cb.c2w) and np.allclose(ca.intr, cb.intr) and ca.distortion == cb.distortion
        assert ca.size == (W, H)
    assert np.allclose(a.points, pts) and np.allclose(b.points, pts)


# -- distortion ---------------------------------------------------------------------------------------------------


def _grid(x, y, step=0.25, width=0.012, vertical=True):
    """Straight lines at multiples of ``step`` in normalised coordinates (1 on a line, 0 between)."""
    dx = np.abs((x + step / 2) % step - step / 2) if vertical else np.inf
    dy = np.abs((y + step / 2) % step - step / 2)
    return np.exp(-((np.minimum(dx, dy) / width) ** 2))


def test_a_distorted_grid_is_straightened():
    Wg, Hg = 160, 120
    intr = np.array([100.0, 100.0, 80.0, 60.0])
    d = Distortion.make("opencv", [-0.25, 0.06, 0.002, -0.001])
    v, u = np.mgrid[0:Hg, 0:Wg] + 0.5
    xd, yd = (u - intr[2]) / intr[0], (v - intr[3]) / intr[1]
    x, y = d.undistort_points(xd, yd)
    assert np.allclose(np.stack(d.distort(x, y)), np.stack([xd, yd]), atol=1e-9)  # the inverse is exact
    distorted = _grid(x, y)[..., None].astype(np.float32)
    ideal = _grid(xd, yd)  # the same pixels through a pinhole
    out = undistort_image(distorted, intr, d)[..., 0]
    core = (slice(8, -8), slice(8, -8))
    assert np.abs(out - ideal)[core].mean() < 0.25 * np.abs(distorted[..., 0] - ideal)[core].mean()
    # the line y_n = 0.25 (row 85, horizontal lines only): straight after, bent before
    distorted = _grid(x, y, vertical=False)[..., None].astype(np.float32)
    out = undistort_image(distorted, intr, d)[..., 0]
    band = slice(78, 93)
    rows = np.arange(Hg)[band, None] + 0.5

    def line_rows(img):
        w = img[band, 10:-10]
        return (w * rows).sum(0) / w.sum(0)

    assert np.ptp(line_rows(out)) < 0.3 and abs(line_rows(out).mean() - 85.0) < 0.3
    assert np.ptp(line_rows(distorted[..., 0])) > 2.0


def test_fisheye_inverse_and_identity():
    d = Distortion.make("fisheye", [0.05, -0.01, 0.002, 0.0])
    x, y = np.meshgrid(np.linspace(-1, 1, 9), np.linspace(-0.8, 0.8, 7))
    xd, yd = d.distort(x, y)
    assert np.allclose(np.stack(d.undistort_points(xd, yd)), np.stack([x, y]), atol=1e-9)
    assert Distortion.make("opencv", [0, 0, 0, 0]) is None


# -- through prepare ---------------------------------------------------------------------------------------------

RES, DIST, FOV = 32, 4.0, 30.0


def _disk_folder(tmp: Path, names, res=RES, r=0.3):
    d = tmp / "images"
    d.mkdir(exist_ok=True)
    yy, xx = np.mgrid[0:res, 0:res] + 0.5
    inside = ((xx / res - 0.5) ** 2 + (yy / res - 0.5) ** 2) < r * r
    img = np.zeros((res, res, 4), np.float32)
    img[inside, :3] = (0.8, 0.3, 0.2)
    img[..., 3] = inside
    for n in names:
        io.write_png(d / f"{n}.png", img)
    return d


def _rig_scene(n=4):
    cams = rig_cameras(n, DIST, FOV, RES)
    return [f"v{i}" for i in range(n)], [c.c2w for c in cams], [c.intr for c in cams]


def _write_colmap_rig(folder: Path, names, c2ws, intrs, points=None, model="PINHOLE", extra=()):
    global W, H
    saved = W, H
    W = H = RES
    try:
        return write_colmap_text(folder, names, c2ws, intrs, points, model, extra)
    finally:
        W, H = saved


def test_prepare_reads_a_colmap_model_and_centres_on_its_points(tmp_path):
    names, c2ws, intrs = _rig_scene()
    images = _disk_folder(tmp_path, names)
    rng = np.random.default_rng(0)
    obj = rng.normal(size=(40, 3))
    obj = 0.2 * obj / np.linalg.norm(obj, axis=1, keepdims=True)
    obj = np.concatenate([obj, -obj]) + np.array([0.05, 0.0, 0.0])  # the object's points, centred at (0.05, 0, 0)
    background = rng.uniform(-6, 6, size=(60, 3)) * np.array([1, 1, 0]) + np.array([0, 0, -1.5])  # a floor
    model = _write_colmap_rig(tmp_path / "sparse" / "0", names, c2ws, intrs, np.concatenate([obj, background]))
    cap = prepare(images, resolution=RES, distance=DIST, fov_deg=FOV, cameras=tmp_path)
    assert cap.info["camera_format"] == "COLMAP"
    assert "sparse points" in cap.info["centre_source"]
    assert np.allclose(cap.info["centre"], [0.05, 0, 0], atol=1e-6)  # the floor's points are left out
    M = np.array(cap.info["world_to_asset"])
    for c2w, out in zip(c2ws, cap.c2w):
        assert np.allclose(M @ np.append(c2w[:3, 3], 1), np.append(out[:3, 3], 1), atol=1e-9)
    # without points: the cameras' common focus (the origin here) as before
    (model / "points3D.txt").unlink()
    cap = prepare(images, resolution=RES, distance=DIST, fov_deg=FOV, cameras=model / "cameras.txt")
    assert np.allclose(cap.c2w, np.stack(c2ws), atol=1e-6) and np.allclose(cap.intr, np.stack(intrs), atol=1e-6)


def test_prepare_undistorts_before_anything_else(tmp_path):
    names, c2ws, intrs = _rig_scene()
    images = _disk_folder(tmp_path, names)
    model = _write_colmap_rig(tmp_path / "m", names, c2ws, intrs, None, "OPENCV", (-1.0, 0.0, 0.0, 0.0))
    cap = prepare(images, resolution=RES, distance=DIST, fov_deg=FOV, cameras=model)
    assert cap.info["undistorted"]["v0"] == {"model": "opencv", "k1": -1.0, "k2": 0.0, "p1": 0.0, "p2": 0.0,
                                             "k3": 0.0, "k4": 0.0, "k5": 0.0, "k6": 0.0}  # fmt: skip
    # barrel distortion undone: the disk grows (its edge moves outwards)
    plain = prepare(
        images,
        resolution=RES,
        distance=DIST,
        fov_deg=FOV,
        cameras=_write_colmap_rig(tmp_path / "p", names, c2ws, intrs),
    )
    assert cap.alpha.sum() > plain.alpha.sum() * 1.03


# -- bad input: one line naming the file and the field --------------------------------------------------------------


def _one_line(e: pytest.ExceptionInfo, *parts: str):
    msg = str(e.value)
    assert "\n" not in msg, msg
    for p in parts:
        assert p in msg, (p, msg)


def test_a_camera_file_for_other_images_names_the_file(tmp_path):
    names, c2ws, intrs = _rig_scene()
    images = _disk_folder(tmp_path, names)
    other = _write_colmap_rig(tmp_path / "other", [f"x{i}" for i in range(3)], c2ws[:3], intrs[:3])
    with pytest.raises(CaptureError) as e:
        prepare(images, resolution=RES, distance=DIST, fov_deg=FOV, cameras=other)
    _one_line(e, "images.txt", "3 cameras name none of the 4 photos", "other images")
    llff = write_llff(tmp_path / "poses_bounds.npy", c2ws[:3], intrs[:3])
    with pytest.raises(CaptureError) as e:
        prepare(images, resolution=RES, distance=DIST, fov_deg=FOV, cameras=llff)
    _one_line(e, "poses_bounds.npy", "3 cameras for 4 images")
    (tmp_path / "bad.npy").write_bytes(b"not numpy")
    with pytest.raises(CaptureError) as e:
        read_camera_set(tmp_path / "bad.npy")
    _one_line(e, "bad.npy")
    np.save(tmp_path / "wrong.npy", np.zeros((3, 12)))
    with pytest.raises(CaptureError) as e:
        read_camera_set(tmp_path / "wrong.npy")
    _one_line(e, "wrong.npy", "N x 17")
    np.savez(tmp_path / "cams.npz", something=np.eye(4))
    with pytest.raises(CaptureError) as e:
        read_camera_set(tmp_path / "cams.npz")
    _one_line(e, "cams.npz", "world_mat_0")


def _transforms(path: Path, names, c2ws, **top):
    frames = [
        {
            **({"file_path": f"images/{n}.png"} if n is not None else {}),
            "transform_matrix": camera.c2w_to_blender(c).tolist(),
        }
        for n, c in zip(names, c2ws)
    ]
    path.write_text(json.dumps({"camera_angle_x": math.radians(FOV), "w": RES, "h": RES, "frames": frames, **top}))
    return path


def test_a_json_camera_file_naming_other_images_is_refused_even_when_the_counts_agree(tmp_path):
    """Names decide: a transforms.json / OpenCV file whose cameras name none of the photos (same count) is one line
    naming the file, and so is one that names some of them; only a file that names no images is taken in order."""
    names, c2ws, intrs = _rig_scene()
    images = _disk_folder(tmp_path, names)
    other = _transforms(tmp_path / "other.json", [f"r_{i}" for i in range(4)], c2ws)
    with pytest.raises(CaptureError) as e:
        prepare(images, resolution=RES, distance=DIST, fov_deg=FOV, cameras=other)
    _one_line(e, "other.json", "4 cameras name none of the 4 photos", "'r_0'", "'v0'", "other images")
    opencv = tmp_path / "opencv.json"
    opencv.write_text(
        json.dumps(
            {
                "cameras": [
                    {"image": f"IMG_{i}.jpg", "c2w": c.tolist(), "intrinsics": k.tolist()}
                    for i, (c, k) in enumerate(zip(c2ws, intrs))
                ]
            }
        )
    )
    with pytest.raises(CaptureError) as e:
        prepare(images, resolution=RES, distance=DIST, fov_deg=FOV, cameras=opencv)
    _one_line(e, "opencv.json", "name none of the 4 photos", "'IMG_0'")
    some = _transforms(tmp_path / "some.json", ["v0", "v1", "x2", "x3"], c2ws)
    with pytest.raises(CaptureError) as e:
        prepare(images, resolution=RES, distance=DIST, fov_deg=FOV, cameras=some)
    _one_line(e, "some.json", "no camera for image(s) ['v2', 'v3']")
    unnamed = _transforms(tmp_path / "unnamed.json", [None] * 4, c2ws)
    cap = prepare(images, resolution=RES, distance=DIST, fov_deg=FOV, cameras=unnamed)
    assert np.allclose(cap.c2w, np.stack(c2ws), atol=1e-6)
    with pytest.raises(CaptureError) as e:
        prepare(
            images,
            resolution=RES,
            distance=DIST,
            fov_deg=FOV,
            cameras=_transforms(tmp_path / "u3.json", [None] * 3, c2ws[:3]),
        )
    _one_line(e, "u3.json", "3 cameras for 4 images", "name no images")


def test_malformed_colmap_files_name_the_file(tmp_path):
    names, c2ws, intrs = _scene(n=2)
    m = write_colmap_text(tmp_path / "m", names, c2ws, intrs)
    (m / "cameras.txt").write_text(f"1 FOV {W} {H} 50 50 32 24 0.9\n2 PINHOLE {W} {H} 50 50 32 24\n")
    with pytest.raises(CaptureError) as e:
        read_camera_set(m)
    _one_line(e, "cameras.txt: line 1", "FOV is not supported")
    (m / "cameras.txt").write_text(f"1 OPENCV {W} {H} 50 50 32 24\n")
    with pytest.raises(CaptureError) as e:
        read_camera_set(m)
    _one_line(e, "cameras.txt: line 1", "OPENCV takes 8 parameters, got 4")
    (m / "cameras.txt").write_text(f"1 PINHOLE {W} {H} 50 50 32 24\n")
    with pytest.raises(CaptureError) as e:
        read_camera_set(m)
    _one_line(e, "images.txt", "camera id 2 is not in cameras.txt")
    b = write_colmap_binary(tmp_path / "b", names, c2ws, intrs)
    (b / "images.bin").write_bytes((b / "images.bin").read_bytes()[:40])
    with pytest.raises(CaptureError) as e:
        read_camera_set(b)
    _one_line(e, "images.bin", "truncated")
    (tmp_path / "empty").mkdir()
    with pytest.raises(CaptureError) as e:
        read_camera_set(tmp_path / "empty")
    _one_line(e, "empty", "no COLMAP model")


@pytest.mark.parametrize(
    "fields,parts",
    [
        ({"k1": -3.0}, ["k1=-3", "folds back"]),
        ({"k1": 0.1, "p1": 0.3}, ["p1=0.3", "tangential"]),
        ({"k4": 0.1}, ["'k4'", "OPENCV_FISHEYE"]),
        ({"k1": "a lot"}, ["'k1'", "not a number"]),
    ],
)
def test_distortion_out_of_range_names_the_file_and_field(tmp_path, fields, parts):
    names, c2ws, intrs = _rig_scene()
    images = _disk_folder(tmp_path, names)
    frames = [
        {"file_path": f"images/{n}.png", "transform_matrix": camera.c2w_to_blender(c).tolist(), **fields}
        for n, c in zip(names, c2ws)
    ]
    path = tmp_path / "transforms.json"
    path.write_text(json.dumps({"camera_angle_x": math.radians(FOV), "w": RES, "h": RES, "frames": frames}))
    with pytest.raises(CaptureError) as e:
        prepare(images, resolution=RES, distance=DIST, fov_deg=FOV, cameras=path)
    _one_line(e, "transforms.json", *parts)


@pytest.mark.parametrize(
    "model,extra,parts",
    [
        ("SIMPLE_RADIAL", [-2.5], ["k1=-2.5", "folds back"]),
        ("OPENCV", [0.0, 0.0, 0.0, 0.5], ["p2=0.5", "tangential"]),
        ("OPENCV_FISHEYE", [-3.0, 0.0, 0.0, 0.0], ["k1=-3", "fisheye distortion out of range"]),
    ],
)
def test_colmap_distortion_out_of_range_names_the_file_and_photo(tmp_path, model, extra, parts):
    names, c2ws, intrs = _rig_scene()
    images = _disk_folder(tmp_path, names)
    if model == "SIMPLE_RADIAL":  # f, cx, cy, then k1
        path = _write_colmap_rig(tmp_path / "m", names, c2ws, intrs, model="SIMPLE_PINHOLE", extra=extra)
        text = (path / "cameras.txt").read_text().replace("SIMPLE_PINHOLE", "SIMPLE_RADIAL")
        (path / "cameras.txt").write_text(text)
    else:
        path = _write_colmap_rig(tmp_path / "m", names, c2ws, intrs, model=model, extra=extra)
    with pytest.raises(CaptureError) as e:
        prepare(images, resolution=RES, distance=DIST, fov_deg=FOV, cameras=path)
    _one_line(e, str(path), "camera of v0", *parts)


def test_opencv_file_distortion_coefficients(tmp_path):
    names, c2ws, intrs = _scene(n=2)
    entries = [
        {
            "name": n,
            "c2w": c.tolist(),
            "intrinsics": k.tolist(),
            "width": W,
            "height": H,
            "dist": [-0.1, 0.01, 0, 0, 0.001],
        }
        for n, c, k in zip(names, c2ws, intrs)
    ]
    (tmp_path / "c.json").write_text(json.dumps({"cameras": entries, "up": [0, 0, 2]}))
    cs = read_camera_set(tmp_path / "c.json", fallback=read_cameras)
    assert dict(cs.cams)[names[0]].distortion == Distortion("opencv", (-0.1, 0.01, 0.0, 0.0, 0.001, 0.0, 0.0, 0.0))
    assert np.allclose(cs.up, [0, 0, 1])
    entries[0]["dist"] = [0.1, 0.2, 0.3]
    (tmp_path / "c.json").write_text(json.dumps({"cameras": entries}))
    with pytest.raises(CaptureError) as e:
        read_camera_set(tmp_path / "c.json", fallback=read_cameras)
    _one_line(e, "c.json", "'dist' has 3 values")
