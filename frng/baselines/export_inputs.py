"""The inputs image-based relighting methods take, exported per test object and target view (stage
``frng export-image-inputs``): "one photo + one target map" for Neural Gaffer, DiLightNet, DiffusionRenderer and
LightSwitch run elsewhere; their outputs come back through ``baselines.external`` (:mod:`frng.baselines.external`,
docs/baselines.md). Layout of the output folder::

    index.json                                   objects, views, lights, conventions, the layout results go back in
    {obj}/{view}/image.png                       the target view under the object's input light, 8-bit sRGB, straight
                                                 alpha (RGBA; the object's mask in A)
    {obj}/{view}/image.exr                       the same, linear premultiplied RGBA (as the dataset stores it)
    {obj}/{view}/mask.png                        the mask (8-bit grey, alpha x 255)
    {obj}/{view}/camera.json                     c2w (OpenCV), intrinsics (fx, fy, cx, cy), width, height, fov_deg, and
                                                 Neural Gaffer's pose: the 3x4 world-to-camera in Blender's camera
                                                 convention (x right, y up, looking along -z)
    {obj}/{view}/envmaps/{light}.exr             each target light, world frame (frng.render.envmap: Blender's equirect
                                                 convention, Z up), linear HDR
    {obj}/{view}/envmaps_camera/{light}.exr      the same map rotated into the view's camera frame as Neural Gaffer's
                                                 preprocessing does (:func:`camera_frame_map`), linear HDR
    {obj}/{view}/envmaps_camera/{light}_ldr.png  ... its LDR input: clip to [0, 1], ^(1/2.2), 256 x 256
    {obj}/{view}/envmaps_camera/{light}_hdr.png  ... its HDR input: log1p(10 E) / max, 256 x 256

Neural Gaffer's camera-frame convention (its ``scripts/generate_bg_and_rotate_envir_map.py``,
``rotate_and_preprcess_envir_map``): an equirect with the same (u, v) <-> direction convention as this project's,
whose +Y direction (u = 0.25, the horizon) is the camera's viewing direction, +Z (the top row) the camera's up and +X
its right: the map's pixel in direction d shows the world radiance from ``R_c2w (d_x, -d_z, d_y)`` in OpenCV camera
axes (``R_c2w (d_x, d_z, -d_y)`` in Blender's, their ``A^T = [[1,0,0],[0,0,1],[0,-1,0]]``).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from frng import io
from frng.baselines.plan import TARGETS_KIND
from frng.plan.layout import ImageInputsFolder, Layout, ObjectFolder
from frng.render import envmap

NG_MAP_SIZE = 256  # Neural Gaffer's LDR / HDR map inputs are 256 x 256 (resized from the equirect)
OPENCV_TO_BLENDER = np.diag([1.0, -1.0, -1.0])
# camera-frame map direction d -> OpenCV camera axes: (d_x, -d_z, d_y)
MAP_TO_OPENCV = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])


class ExportError(ValueError):
    """A file the export reads is missing or unreadable (names it)."""


def camera_frame_map(world_map: np.ndarray, c2w: np.ndarray) -> np.ndarray:
    """The (H, 2H, 3) world-frame map ``world_map`` rotated into the camera frame of ``c2w`` ((4, 4) OpenCV
    camera-to-world) in Neural Gaffer's convention (module docstring): E_cam(d) = E_world(R_c2w M d),
    M = :data:`MAP_TO_OPENCV`. Returns (H, 2H, 3) float32."""
    from frng.benchmarks.common import rotate_map

    R = np.asarray(c2w, dtype=np.float64)[:3, :3] @ MAP_TO_OPENCV  # camera-map direction -> world direction
    return rotate_map(np.asarray(world_map, np.float32), R.T).astype(np.float32)  # rotate_map: E(R^T d)


def neural_gaffer_pngs(cam_map: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Neural Gaffer's two map inputs of a camera-frame map (H, W, 3) linear: LDR = clip(E, 0, 1)^(1/2.2), HDR =
    log1p(10 E) / its max; both resized (bilinear) to 256 x 256, in [0, 1]."""
    from skimage.transform import resize

    ldr = np.clip(cam_map, 0.0, 1.0) ** (1.0 / 2.2)
    hdr = np.log1p(10.0 * np.clip(cam_map, 0.0, None))
    hdr = hdr / max(float(hdr.max()), 1e-12)
    size = (NG_MAP_SIZE, NG_MAP_SIZE)
    return tuple(np.clip(resize(x, size, order=1, anti_aliasing=True), 0, 1).astype(np.float32) for x in (ldr, hdr))


def camera_record(view: dict) -> dict:
    """camera.json of one view record (a meta.json ``views`` entry)."""
    c2w = np.asarray(view["c2w"], dtype=np.float64).reshape(4, 4)
    fx, fy, cx, cy = (float(x) for x in view["intrinsics"])
    blender_c2w = c2w.copy()
    blender_c2w[:3, :3] = c2w[:3, :3] @ OPENCV_TO_BLENDER
    w2c_blender = np.linalg.inv(blender_c2w)[:3, :4]
    return {
        "name": view["name"],
        "width": int(view["width"]),
        "height": int(view["height"]),
        "c2w_opencv": c2w.tolist(),
        "intrinsics": [fx, fy, cx, cy],
        "fov_deg": math.degrees(2.0 * math.atan(0.5 * int(view["width"]) / fx)),
        "w2c_blender_3x4": w2c_blender.tolist(),
        "conventions": "world: Z up (frng); c2w_opencv: x right, y down, z forward; w2c_blender_3x4: Neural Gaffer's "
        "pose (Blender camera: x right, y up, looking along -z)",
    }


def export_object(results: str | Path, oid: str, out: str | Path) -> list[str]:
    """Write one test object's inputs into ``out/{obj}/`` (module docstring). Returns the view names. Reads
    ``{results}/baselines/views/{obj}/meta.json`` and its ``targets/{light}/{view}.exr``, the object's meta.json
    (target lights, map files)."""
    L = Layout(results)
    try:
        vmeta = io.read_json(L.baseline_views_meta(oid))
        light_in, views = vmeta["light"], vmeta["views"][TARGETS_KIND]
        meta = io.read_json(L.object_meta(oid))
        lights = {l: Path(results) / meta["lights"][l]["file"] for l in meta["target_lights"]}
    except (FileNotFoundError, ValueError, KeyError) as e:
        raise ExportError(f"object {oid}: cannot read {L.baseline_views_meta(oid)} / {L.object_meta(oid)} ({e})") from e
    maps = {}
    for l, f in lights.items():
        try:
            maps[l] = envmap.read(f)
        except envmap.EnvMapError as e:
            raise ExportError(f"environment map: {e}") from e
    folder = ObjectFolder(L.baseline_views_dir(oid))
    root = Path(out) / oid
    for v in views:
        d = root / v["name"]
        img = io.read_rgba(folder.image(TARGETS_KIND, light_in, v["name"]), require_alpha=True)
        a = np.clip(img[..., 3:4], 0.0, 1.0)
        straight = np.where(a > 0, img[..., :3] / np.maximum(a, 1e-8), 0.0)
        io.write_exr(d / "image.exr", img, ["R", "G", "B", "A"])
        io.write_png(d / "image.png", np.concatenate([io.srgb_encode(straight), a], -1))
        io.write_png(d / "mask.png", a[..., 0])
        io.write_json(d / "camera.json", camera_record(v) | {"input_light": light_in})
        for l, m in maps.items():
            envmap.write(d / "envmaps" / f"{l}.exr", m)
            cam = camera_frame_map(m, np.asarray(v["c2w"]))
            envmap.write(d / "envmaps_camera" / f"{l}.exr", cam)
            ldr, hdr = neural_gaffer_pngs(cam)
            io.write_png(d / "envmaps_camera" / f"{l}_ldr.png", ldr)
            io.write_png(d / "envmaps_camera" / f"{l}_hdr.png", hdr)
    return [v["name"] for v in views]


def export(results: str | Path, objects: list[str], out: str | Path) -> Path:
    """Export every object of ``objects`` and write ``out/index.json``. Returns the index's path."""
    index = {
        "what": "inputs of image-based relighting methods: each target view under the object's input light + the "
        "target environment maps (frng export-image-inputs; docs/baselines.md)",
        "results_layout": "{path}/{obj}/{light}/{view}.png|exr, read by baselines.external (docs/baselines.md)",
        "objects": {},
    }
    for oid in objects:
        views = export_object(results, oid, out)
        meta = io.read_json(Layout(results).object_meta(oid))
        index["objects"][oid] = {"views": views, "lights": list(meta["target_lights"])}
    path = Path(ImageInputsFolder(out).index())
    io.write_json(path, index)
    return path
