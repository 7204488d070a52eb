"""Cycles scene set-up, cameras, G-buffer passes and rendering to a file.

Render output is a multilayer float32 EXR; :func:`read_passes` turns it into named numpy arrays.
Camera poses come in as OpenCV camera-to-world matrices and are converted with :mod:`frng.camera` only.
"""

from __future__ import annotations

import contextlib
import math
import os
import sys
import time
from pathlib import Path

import bpy
import numpy as np
from mathutils import Matrix

from frng import camera, io

# View-layer AOVs written by every frng material (see frng.blender.materials.add_aov_outputs).
AOVS = (("albedo", "COLOR"), ("roughness", "VALUE"), ("metallic", "VALUE"))


def new_scene(
    resolution: int | tuple[int, int], spp: int, threads: int, seed: int, transparent: bool = True
) -> bpy.types.Scene:
    """Empty factory scene rendering with Cycles on the CPU, fixed seed and thread count, no denoising.

    resolution: square size or (width, height) in pixels. Output: multilayer float32 EXR (ZIP).
    """
    with quiet():
        bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    w, h = (resolution, resolution) if isinstance(resolution, int) else resolution
    r = scene.render
    r.engine = "CYCLES"
    r.resolution_x, r.resolution_y, r.resolution_percentage = int(w), int(h), 100
    r.film_transparent = transparent
    r.threads_mode = "FIXED"
    r.threads = int(threads)
    r.use_persistent_data = True
    c = scene.cycles
    c.device = "CPU"
    c.samples = int(spp)
    c.use_adaptive_sampling = False
    c.use_denoising = False
    c.seed = int(seed) % (2**31 - 1)
    c.use_animated_seed = False
    scene.view_settings.view_transform = "Standard"
    scene.view_settings.look = "None"
    scene.render.image_settings.file_format = "OPEN_EXR_MULTILAYER"
    scene.render.image_settings.color_depth = "32"
    scene.render.image_settings.exr_codec = "ZIP"
    return scene


DENOISE_PREFILTERS = ("none", "fast", "accurate")  # Cycles' denoising_prefilter, lower case (render.denoise_prefilter)


def set_sampling(
    scene: bpy.types.Scene,
    spp: int,
    denoise: bool,
    clamp_direct: float,
    clamp_indirect: float,
    prefilter: str,
) -> None:
    """Cycles' sampling of ``scene``: ``spp`` samples per pixel; ``denoise``: OpenImageDenoise (CPU, quality HIGH) on
    the final render, fed the albedo and normal passes, else no denoising; ``prefilter`` (one of
    :data:`DENOISE_PREFILTERS`): how OIDN treats those passes (``none``: as noise-free, ``fast`` / ``accurate``:
    denoised first); ``clamp_direct`` / ``clamp_indirect``: Cycles' per-sample clamps of direct / indirect light (0 =
    no clamp; Blender's defaults 0 / 10). The render's ``Combined`` layer is the denoised image; Blender adds a
    ``Noisy Image`` layer beside it."""
    if prefilter not in DENOISE_PREFILTERS:
        raise ValueError(f"denoise prefilter {prefilter!r}: expected one of {', '.join(DENOISE_PREFILTERS)}")
    c = scene.cycles
    c.samples = int(spp)
    c.use_denoising = bool(denoise)
    if denoise:
        c.denoiser = "OPENIMAGEDENOISE"
        c.denoising_input_passes = "RGB_ALBEDO_NORMAL"
        c.denoising_prefilter = prefilter.upper()
        c.denoising_quality = "HIGH"
        c.denoising_use_gpu = False
    c.sample_clamp_direct = float(clamp_direct)
    c.sample_clamp_indirect = float(clamp_indirect)


def enable_gbuffer_passes(scene: bpy.types.Scene) -> None:
    """Depth (Z), world normals and the albedo/roughness/metallic AOVs in every render (+3-6% time)."""
    vl = scene.view_layers[0]
    vl.use_pass_z = True
    vl.use_pass_normal = True
    existing = {a.name for a in vl.aovs}
    for name, kind in AOVS:
        if name not in existing:
            aov = vl.aovs.add()
            aov.name, aov.type = name, kind


def add_camera(scene: bpy.types.Scene, fov_deg: float) -> bpy.types.Object:
    """Perspective camera with a horizontal field of view ``fov_deg`` (matches frng.camera.intrinsics_from_fov)."""
    data = bpy.data.cameras.new("frng_camera")
    data.type = "PERSP"
    data.sensor_fit = "HORIZONTAL"
    data.angle = math.radians(fov_deg)
    data.clip_start, data.clip_end = 0.01, 100.0
    obj = bpy.data.objects.new("frng_camera", data)
    scene.collection.objects.link(obj)
    scene.camera = obj
    return obj


def set_camera_pose(cam: bpy.types.Object, c2w_opencv: np.ndarray) -> None:
    """Place the camera from an OpenCV camera-to-world (4, 4)."""
    cam.matrix_world = Matrix(camera.c2w_to_blender(np.asarray(c2w_opencv)).tolist())


@contextlib.contextmanager
def quiet():
    """Silence Blender's C-level stdout (render progress spam) for the block."""
    sys.stdout.flush()
    fd = os.dup(1)
    devnull = os.open(os.devnull, os.O_WRONLY)
    try:
        os.dup2(devnull, 1)
        yield
    finally:
        sys.stdout.flush()
        os.dup2(fd, 1)
        os.close(fd)
        os.close(devnull)


def render_to(scene: bpy.types.Scene, path: str | Path) -> float:
    """Render the scene's camera into ``path`` (format from the scene's image settings); returns seconds."""
    scene.render.filepath = str(path)
    t0 = time.perf_counter()
    with quiet():
        bpy.ops.render.render(write_still=True)
    dt = time.perf_counter() - t0
    if not Path(path).exists():
        raise RuntimeError(f"Blender did not write {path}")
    return dt


def read_passes(path: str | Path) -> dict[str, np.ndarray]:
    """A rendered multilayer EXR -> arrays (H, W, C) float32 keyed by pass.

    Keys: ``rgba`` (4, premultiplied), ``depth`` (1, camera-axis distance, 1e10 where nothing was hit),
    ``normal`` (3, world space, averaged over samples), ``albedo`` (3), ``roughness`` (1), ``metallic`` (1)
    -- the G-buffer keys only when the passes were enabled.
    """
    ch = io.read_exr_channels(path)

    def grab(layer: str, comps: str) -> np.ndarray | None:
        names = [f"ViewLayer.{layer}.{c}" for c in comps]
        if not all(n in ch for n in names):
            return None
        return np.stack([ch[n] for n in names], axis=-1)

    out = {"rgba": grab("Combined", "RGBA")}
    if out["rgba"] is None:
        raise io.ImageError(f"{path}: no Combined RGBA layer; has {sorted(ch)}")
    for key, layer, comps in (("depth", "Depth", "Z"), ("normal", "Normal", "XYZ"), ("albedo", "albedo", "RGB")):
        arr = grab(layer, comps)
        if arr is not None:
            out[key] = arr
    for key in ("roughness", "metallic"):
        arr = grab(key, "X")
        if arr is None:
            arr = grab(key, "V")
        if arr is not None:
            out[key] = arr
    return out
