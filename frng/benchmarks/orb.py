"""Stanford-ORB (``blender_HDR`` release): reader and writer of its published layout.

Official code read (github.com/StanfordORB/Stanford-ORB):

- ``orb/datasets/mymethod.py`` ``BlenderDataset``: ``{data_root}/transforms_{train,test}.json`` and
  ``transforms_novel.json`` (frames of the OTHER scenes of the same object, each with ``scene_name`` and its own
  ``camera_angle_x``; their ``file_path`` is relative to ``{data_root}/../{scene_name}``); images
  ``{file_path}.exr`` (HDR, linear) or ``.png`` (LDR), masks ``{dirname(file_path)}_mask/{basename}.png``;
  ``transform_matrix`` used directly as camera-to-world in NeRF/OpenGL camera axes (x right, y up, looking along
  -z), ``focal = 0.5 * 512 / tan(0.5 * camera_angle_x)`` at ``BENCHMARK_RESOLUTION = 512`` (``orb/constant.py``;
  the 2048 px images are downsized 4x), principal point at the centre. Here: :func:`frng.camera.c2w_from_blender`
  (the same axis flip), focal from the files' own width.
- ``orb/utils/env_map.py`` ``env_map_to_cam_to_world_by_convention``: the ground-truth maps
  ``ground_truth/{scene}/env_map/{view}.exr`` are given in the view's CAMERA frame ("ours": +Z at the left edge,
  +Y at the top); pixel (col, row) of a W x H map looks along ``theta = -pi/2 + 2 pi col / (W - 1)``,
  ``phi = pi row / (H - 1)``, ``d = (-cos(theta) sin(phi), cos(phi), -sin(theta) sin(phi))`` (camera axes), and
  the world map is ``E_world(d) = E_cam(R^T d)`` with ``R`` the view's (OpenGL) camera-to-world rotation, sampled
  bilinearly (``cv2.remap``, pixel index = coordinate). :func:`camera_map_to_world` does exactly that once, into
  :mod:`frng.render.envmap`'s convention; :func:`world_map_to_camera` is its inverse (the writer).
- ``orb/utils/test.py`` / ``orb/utils/metrics.py``: the relighting metric, :func:`frng.benchmarks.protocols.orb`.

What the import takes: input views from ``transforms_train.json`` (rig-like, :mod:`frng.benchmarks.common`); the
input light = the ground-truth map of the scene's first test view (``transforms_test.json``) in world axes (F-RNG
relights from a KNOWN input light; ORB's methods estimate it); targets = every ``transforms_novel.json`` frame
under its own scene's light (the map of that scene's first novel frame, in world axes: every view of a scene sees
the same environment). World: ORB's (Z up), normalised. ``--ground-truth DIR`` overrides the default
``{PATH}/../../ground_truth``.

The writer (``frng export --layout orb``) writes a curated object as ``blender_HDR/{id}_scene001/`` (train = the
input views, test = the extra input views or else the first input view, under the input light) plus one
``blender_HDR/{id}_scene{002..}/test/`` per target light, ``transforms_novel.json`` in scene001 pointing at them,
and ``ground_truth/{scene}/env_map/{view}.exr`` per test/novel view in that view's camera frame (at 4x the map's height, so the two resamplings of a round trip lose little).
EXRs are RGBA
(linear straight RGB, 0 outside the object, A = mask), masks 8-bit PNG.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from frng import camera, confine, io
from frng.benchmarks.common import (
    BenchmarkError,
    Curated,
    Scene,
    View,
    blender_uv,
    fov_x,
    map_directions,
    need,
    read_exr_rgb,
    read_json,
    read_map,
    read_mask_png,
    read_png,
    sample_map,
)
from frng.render import envmap

LAYOUT = "orb"
PROTOCOL = "orb"


# -- env-map conventions ---------------------------------------------------------------------------------------


def _bilinear_idx(img: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """cv2.remap(INTER_LINEAR) at pixel-index coordinates: x periodic, y clamped."""
    H, W = img.shape[:2]
    y = np.clip(y, 0, H - 1)
    x0, y0 = np.floor(x).astype(int), np.floor(y).astype(int)
    tx, ty = (x - x0)[..., None], (y - y0)[..., None]
    x0m, x1m, y1 = x0 % W, (x0 + 1) % W, np.minimum(y0 + 1, H - 1)
    return (
        (1 - ty) * ((1 - tx) * img[y0, x0m] + tx * img[y0, x1m]) + ty * ((1 - tx) * img[y1, x0m] + tx * img[y1, x1m])
    ).astype(np.float32)


def orb_pixel_dirs(H: int, W: int) -> np.ndarray:
    """Camera-frame direction (H, W, 3) of every ORB map pixel (``env_map.py``)."""
    theta, phi = np.meshgrid(np.linspace(-0.5 * np.pi, 1.5 * np.pi, W), np.linspace(0.0, np.pi, H))
    return np.stack([-np.cos(theta) * np.sin(phi), np.cos(phi), -np.sin(theta) * np.sin(phi)], -1)


def camera_map_to_world(img: np.ndarray, c2w_gl: np.ndarray, height: int | None = None) -> np.ndarray:
    """An ORB camera-frame map -> a world map (frng.render.envmap convention, ``height`` x 2 ``height``)."""
    H, W = img.shape[:2]
    height = height or H
    d_world = map_directions(height)  # (h, 2h, 3)
    d_cam = d_world @ np.asarray(c2w_gl, dtype=np.float64)[:3, :3]  # R^T d as rows
    y = np.arccos(np.clip(d_cam[..., 1], -1, 1)) / np.pi * (H - 1)
    x = ((np.arctan2(d_cam[..., 0], -d_cam[..., 2]) + np.pi) / 2 / np.pi * (W - 1) + W) % W
    return _bilinear_idx(img, x, y)


def world_map_to_camera(world: np.ndarray, c2w_gl: np.ndarray, height: int | None = None) -> np.ndarray:
    """The writer's inverse: a world map (frng.render.envmap convention) -> ORB's camera-frame map of the view."""
    height = height or world.shape[0]
    d_cam = orb_pixel_dirs(height, 2 * height)
    d_world = d_cam @ np.asarray(c2w_gl, dtype=np.float64)[:3, :3].T
    return sample_map(world, *blender_uv(d_world))


# -- reader ----------------------------------------------------------------------------------------------------


def _frames(path: Path) -> dict:
    meta = read_json(path)
    if not isinstance(meta, dict) or "frames" not in meta:
        raise BenchmarkError(f"{path}: missing 'frames' (Stanford-ORB transforms json)")
    if not isinstance(meta["frames"], list) or not all(isinstance(fr, dict) for fr in meta["frames"]):
        raise BenchmarkError(f"{path}: field 'frames' must be a list of objects")
    return meta


def _file_path(fr: dict, where: Path, i: int) -> str:
    fp = fr.get("file_path")
    if not isinstance(fp, str) or not fp:
        raise BenchmarkError(f"{where}: field 'frames[{i}].file_path' must be a non-empty string, got {fp!r}")
    return fp


def _view(root: Path, fr: dict, angle: float, light: str, where: Path, i: int, allow_outside: bool = False) -> View:
    """One frame; its image and mask must lie inside ``root`` (symlinks resolved) unless ``allow_outside``."""
    if "file_path" not in fr or "transform_matrix" not in fr:
        raise BenchmarkError(f"{where}: frame {i} lacks 'file_path' or 'transform_matrix'")
    fp = _file_path(fr, where, i).removeprefix("./")
    field = f"frames[{i}].file_path"
    check = dict(source=where, field=field, allow_outside=allow_outside)
    exr = confine.member(root, fp, suffix=".exr", **check)
    png = confine.member(root, fp, suffix=".png", **check)
    if exr.exists():
        rgb, _ = read_exr_rgb(exr)
        src = exr
    elif png.exists():
        rgb, src = io.srgb_decode(read_png(png)[..., :3]), png
    else:
        raise BenchmarkError(f"{exr}: missing image (Stanford-ORB frame {fp})")
    mask_path = root / (str(Path(fp).parent) + "_mask") / (Path(fp).name + ".png")
    mask = read_mask_png(confine.inside(mask_path, root, **check))
    w = rgb.shape[1]
    focal = 0.5 * w / math.tan(0.5 * angle)
    c2w_gl = confine.finite(fr["transform_matrix"], source=where, field=f"frames[{i}].transform_matrix", shape=(4, 4))
    v = View(
        name=f"{Path(fp).name}",
        c2w=camera.c2w_from_blender(c2w_gl),
        K=np.array([focal, focal, w / 2.0, rgb.shape[0] / 2.0]),
        rgb=np.maximum(rgb, 0.0),
        mask=mask,
        light=light,
        source=str(src),
    )
    v.c2w_gl = c2w_gl  # type: ignore[attr-defined]
    return v


def read(
    path: str | Path,
    ground_truth: str | Path | None = None,
    envmap_height: int | None = None,
    allow_outside: bool = False,
) -> Scene:
    """The scene ``path`` (``blender_HDR/{scene}``). Every file a transforms json names must lie inside its scene
    folder, a ``scene_name`` must be a sibling scene folder's plain name, and the ground-truth maps inside
    ``ground_truth`` (symlinks resolved; :mod:`frng.confine`) unless ``allow_outside``."""
    root = need(Path(path), "Stanford-ORB scene folder (blender_HDR/{scene})")
    scene = root.name
    gt_root = Path(ground_truth) if ground_truth else root.parent.parent / "ground_truth"
    tr_path = need(root / "transforms_train.json", "transforms_train.json (Stanford-ORB layout)")
    train_meta = _frames(tr_path)
    if not train_meta.get("camera_angle_x"):
        raise BenchmarkError(f"{tr_path}: missing 'camera_angle_x'")
    angle = confine.angle(train_meta["camera_angle_x"], source=tr_path, field="camera_angle_x")
    train = [_view(root, fr, angle, scene, tr_path, i, allow_outside) for i, fr in enumerate(train_meta["frames"])]
    te_path = need(root / "transforms_test.json", "transforms_test.json (Stanford-ORB layout)")
    test_meta = _frames(te_path)
    if not test_meta["frames"]:
        raise BenchmarkError(f"{te_path}: no frames (the input light is read from the first test view's map)")

    def gt_map(sname: str, fr: dict, where: Path, i: int) -> np.ndarray:
        p = gt_root / sname / "env_map" / (Path(_file_path(fr, where, i)).name + ".exr")
        p = confine.inside(p, gt_root, source=where, field=f"frames[{i}].file_path", allow_outside=allow_outside)
        if "transform_matrix" not in fr:
            raise BenchmarkError(f"{where}: frame {i} lacks 'file_path' or 'transform_matrix'")
        c2w = confine.finite(fr["transform_matrix"], source=where, field=f"frames[{i}].transform_matrix", shape=(4, 4))
        return camera_map_to_world(read_map(p), c2w, envmap_height)

    lights = {scene: gt_map(scene, test_meta["frames"][0], te_path, 0)}
    nv_path = need(root / "transforms_novel.json", "transforms_novel.json (Stanford-ORB relighting targets)")
    novel = _frames(nv_path)
    test = []
    for i, fr in enumerate(novel["frames"]):
        sname = fr.get("scene_name")
        if not sname:
            raise BenchmarkError(f"{nv_path}: frame {i} lacks 'scene_name'")
        sname = confine.plain_name(sname, source=nv_path, field=f"frames[{i}].scene_name")
        a = confine.angle(fr.get("camera_angle_x", angle), source=nv_path, field=f"frames[{i}].camera_angle_x")
        if not allow_outside:  # the sibling scene folder itself (a symlink out of blender_HDR/)
            confine.inside(root.parent / sname, root.parent, source=nv_path, field=f"frames[{i}].scene_name")
        v = _view(root.parent / sname, fr, a, sname, nv_path, i, allow_outside)
        v.name = f"{sname}/{v.name}"
        if sname not in lights:
            lights[sname] = gt_map(sname, fr, nv_path, i)
        test.append(v)
    return Scene(
        layout=LAYOUT,
        scene=scene,
        path=str(root),
        protocol=PROTOCOL,
        train=train,
        test=test,
        lights=lights,
        input_light=scene,
        notes={"ground_truth": str(gt_root.resolve())},
    )


# -- writer ----------------------------------------------------------------------------------------------------


def _write_frame(folder: Path, split: str, k: int, rgba: np.ndarray) -> str:
    a = rgba[..., 3:4]
    straight = np.where(a > 1e-6, rgba[..., :3] / np.maximum(a, 1e-6), 0.0)  # the loader multiplies by the mask
    io.write_exr(folder / split / f"{k:04d}.exr", np.concatenate([straight, a], -1), channels=["R", "G", "B", "A"])
    io.write_png(folder / f"{split}_mask" / f"{k:04d}.png", np.clip(rgba[..., 3], 0, 1))
    return f"./{split}/{k:04d}"


def _frame(v: dict, fp: str, **extra) -> dict:
    return {"file_path": fp, "transform_matrix": camera.c2w_to_blender(np.asarray(v["c2w"])).tolist(), **extra}


def write(cur: Curated, out: str | Path, scene: str | None = None) -> Path:
    out = Path(out)
    name = scene or cur.oid
    s1 = f"{name}_scene001"
    root = out / "blender_HDR" / s1
    gt = out / "ground_truth"
    angle = fov_x(cur.inputs[0]["intrinsics"], int(cur.inputs[0]["width"]))
    views = cur.inputs + cur.extra
    frames = [
        _frame(v, _write_frame(root, "train", k, cur.image("inputs", cur.input_light, v["name"])))
        for k, v in enumerate(views)
    ]
    io.write_json(root / "transforms_train.json", {"camera_angle_x": angle, "frames": frames})
    tests = cur.extra or cur.inputs[:1]
    frames = []
    world_in = cur.envmap(cur.input_light)
    for k, v in enumerate(tests):
        frames.append(_frame(v, _write_frame(root, "test", k, cur.image("inputs", cur.input_light, v["name"]))))
        c2w_gl = camera.c2w_to_blender(np.asarray(v["c2w"]))
        io.write_exr(gt / s1 / "env_map" / f"{k:04d}.exr", world_map_to_camera(world_in, c2w_gl, 4 * world_in.shape[0]))
    io.write_json(root / "transforms_test.json", {"camera_angle_x": angle, "frames": frames})
    novel = []
    for j, light in enumerate(cur.target_lights):
        sj = f"{name}_scene{j + 2:03d}"
        world = cur.envmap(light)
        for k, v in enumerate(cur.targets):
            fp = _write_frame(out / "blender_HDR" / sj, "test", k, cur.image("targets", light, v["name"]))
            novel.append(_frame(v, fp, scene_name=sj, camera_angle_x=angle))
            c2w_gl = camera.c2w_to_blender(np.asarray(v["c2w"]))
            io.write_exr(gt / sj / "env_map" / f"{k:04d}.exr", world_map_to_camera(world, c2w_gl, 4 * world.shape[0]))
    io.write_json(root / "transforms_novel.json", {"frames": novel})
    return root


__all__ = ["read", "write", "camera_map_to_world", "world_map_to_camera", "envmap"]
