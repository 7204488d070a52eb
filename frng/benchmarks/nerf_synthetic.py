"""NeRF-synthetic (``transforms_{train,val,test}.json``): reader and writer of its published layout.

Official code read: TensoIR's ``dataLoader/blender.py`` (github.com/Haian-Jin/TensoIR) and GS-IR's
``scene/dataset_readers.py``, both readers of the original NeRF release: ``camera_angle_x`` (horizontal FOV,
radians) and ``frames``, each with ``file_path`` (relative, no extension: ``./train/r_0`` -> ``train/r_0.png``)
and ``transform_matrix``, a camera-to-world in Blender/OpenGL camera axes (+X right, +Y up, looking along -Z),
turned into OpenCV with ``@ diag(1, -1, -1, 1)`` (TensoIR) or ``c2w[:3, 1:3] *= -1`` (GS-IR) -- both
:func:`frng.camera.c2w_from_blender`; focal ``0.5 * W / tan(0.5 * camera_angle_x)``, principal point at the
centre. Images: 800 x 800 RGBA PNG, sRGB, straight alpha (composited on white by the readers).

NeRF-synthetic is a novel-view benchmark with ONE light (Blender lamps, no environment map is published), so the
import relights nothing: its test views are the targets under the same light, and F-RNG's known input light is a
stand-in: ``--envmap FILE`` (a 2:1 map, frng.render.envmap convention), else ``{PATH}/../envmaps/{scene}.exr`` when it
exists (what the writer puts there), else a constant white map of radiance 1 (recorded in ``meta.json``).
Protocol: :func:`frng.benchmarks.protocols.nerf_synthetic` (the NeRF/TensoIR one: white background, whole image).

The writer (``frng export --layout nerf-synthetic``) writes the rig input views as ``train/r_{k}.png``, the extra
input views (``in_06 ..``, same light: a novel-view test set) as ``test/r_{k}.png`` and ``val`` = ``test``, plus
the input light as ``envmaps/{scene}.exr`` beside the scene folder.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from frng import camera, confine, io
from frng.benchmarks.common import (
    BenchmarkError,
    Curated,
    Scene,
    View,
    fov_x,
    need,
    read_json,
    read_map,
    read_srgba_png,
    write_srgba_png,
)
from frng.render import envmap

LAYOUT = "nerf-synthetic"
PROTOCOL = "nerf-synthetic"
LIGHT = "scene"


def read_split(root: Path, split: str, light: str = LIGHT, allow_outside: bool = False) -> list[View]:
    """The views of ``transforms_{split}.json``; every ``file_path`` must name a file inside ``root`` (symlinks
    resolved; :func:`frng.confine.member`) unless ``allow_outside``; cameras and the field of view finite."""
    path = root / f"transforms_{split}.json"
    meta = read_json(path)
    if not isinstance(meta, dict) or "camera_angle_x" not in meta or "frames" not in meta:
        raise BenchmarkError(f"{path}: missing 'camera_angle_x' or 'frames' (NeRF-synthetic transforms.json)")
    if not isinstance(meta["frames"], list):
        raise BenchmarkError(f"{path}: field 'frames' must be a list, got {type(meta['frames']).__name__}")
    angle = confine.angle(meta["camera_angle_x"], source=path, field="camera_angle_x")
    views = []
    for i, fr in enumerate(meta["frames"]):
        if not isinstance(fr, dict) or "file_path" not in fr or "transform_matrix" not in fr:
            raise BenchmarkError(f"{path}: frame {i} lacks 'file_path' or 'transform_matrix'")
        fp = fr["file_path"]
        if not isinstance(fp, str):
            raise BenchmarkError(f"{path}: field 'frames[{i}].file_path' must be a string, got {fp!r}")
        png = confine.member(
            root,
            fp.removeprefix("./"),
            source=path,
            field=f"frames[{i}].file_path",
            suffix=".png",
            allow_outside=allow_outside,
        )
        rgb, a = read_srgba_png(png)
        w = rgb.shape[1]
        focal = 0.5 * w / np.tan(0.5 * angle)
        m = confine.finite(fr["transform_matrix"], source=path, field=f"frames[{i}].transform_matrix")
        if m.shape != (4, 4):
            raise BenchmarkError(f"{path}: frame {i} transform_matrix is not 4x4")
        views.append(
            View(
                name=Path(fr["file_path"]).name,
                c2w=camera.c2w_from_blender(m),
                K=np.array([focal, focal, w / 2.0, rgb.shape[0] / 2.0]),
                rgb=rgb,
                mask=a,
                light=light,
                source=str(png),
            )
        )
    return views


def read(
    path: str | Path, envmap_file: str | Path | None = None, split: str = "test", allow_outside: bool = False
) -> Scene:
    root = need(Path(path), "NeRF-synthetic scene folder")
    need(root / "transforms_train.json", "transforms_train.json (NeRF-synthetic layout)")
    train = read_split(root, "train", allow_outside=allow_outside)
    test = read_split(root, split, allow_outside=allow_outside)
    notes = {}
    default = root.parent / "envmaps" / f"{root.name}.exr"
    if envmap_file is None and default.exists():
        envmap_file = default
    if envmap_file is not None:
        light = read_map(Path(envmap_file))
        notes["envmap"] = str(Path(envmap_file).resolve())
    else:
        light = np.ones((64, 128, 3), dtype=np.float32)
        notes["envmap"] = "constant radiance 1 (NeRF-synthetic publishes no light)"
    return Scene(
        layout=LAYOUT,
        scene=root.name,
        path=str(root),
        protocol=PROTOCOL,
        train=train,
        test=test,
        lights={LIGHT: light},
        input_light=LIGHT,
        notes=notes,
    )


def _transforms(path: Path, views: list[dict], folder: str, images: list[np.ndarray]) -> None:
    frames = []
    for k, (v, rgba) in enumerate(zip(views, images)):
        write_srgba_png(path.parent / folder / f"r_{k}.png", rgba)
        frames.append(
            {
                "file_path": f"./{folder}/r_{k}",
                "rotation": 0.0,
                "transform_matrix": camera.c2w_to_blender(np.asarray(v["c2w"], dtype=np.float64)).tolist(),
            }
        )
    io.write_json(path, {"camera_angle_x": fov_x(views[0]["intrinsics"], int(views[0]["width"])), "frames": frames})


def write(cur: Curated, out: str | Path, scene: str | None = None) -> Path:
    if not cur.extra:
        raise BenchmarkError(
            f"{cur.oid}: has no extra input views (in_06 ..) to serve as NeRF-synthetic test views "
            f"under the input light (render.extra_input_views = 0)"
        )
    out = Path(out)
    root = out / (scene or cur.oid)
    L = cur.input_light
    _transforms(
        root / "transforms_train.json", cur.inputs, "train", [cur.image("inputs", L, v["name"]) for v in cur.inputs]
    )
    test_imgs = [cur.image("inputs", L, v["name"]) for v in cur.extra]
    _transforms(root / "transforms_test.json", cur.extra, "test", test_imgs)
    _transforms(root / "transforms_val.json", cur.extra, "val", test_imgs)
    envmap.write(out / "envmaps" / f"{root.name}.exr", cur.envmap(L))
    return root
