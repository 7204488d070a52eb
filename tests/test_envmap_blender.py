"""frng.render.envmap's equirect convention (and frng.camera's OpenCV convention) match how Cycles lights a scene.

A mirror sphere is lit by a map holding one small bright blob; the brightest pixel Cycles renders must be
where our own ray tracing (frng.camera rays -> sphere -> reflect -> frng.render.envmap direction) predicts it.
"""

import math

import numpy as np
import pytest
import torch

from frng import camera
from frng.render import envmap

pytestmark = pytest.mark.blender

SIGMA_DEG = 4.0


def blob_map(h: int, w: int, direction: np.ndarray) -> np.ndarray:
    d = envmap.pixel_directions(h, w, dtype=torch.float64).numpy()
    ang = np.degrees(np.arccos(np.clip(d @ direction, -1, 1)))
    rad = 0.02 + 300.0 * np.exp(-((ang / SIGMA_DEG) ** 2))
    return np.repeat(rad[..., None], 3, -1).astype(np.float32)


def predicted_highlight(c2w: np.ndarray, K: np.ndarray, res: int, blob: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(row, col) of the pixel whose mirror reflection off the unit sphere points closest to ``blob``; sphere mask."""
    o, d = camera.pixel_rays(torch.tensor(c2w[None]), torch.tensor(K[None]), res, res)
    o, d = o[0].numpy(), d[0].numpy()
    b = np.sum(o * d, -1)
    disc = b * b - (np.sum(o * o, -1) - 1.0)
    hit = disc > 0
    t = -b - np.sqrt(np.maximum(disc, 0))
    n = o + t[..., None] * d
    r = d - 2 * np.sum(d * n, -1, keepdims=True) * n
    score = np.where(hit, r @ blob, -2.0)
    return np.array(np.unravel_index(np.argmax(score), score.shape)), hit


def test_mirror_sphere_highlight_lands_where_the_convention_says(tmp_path):
    import bpy

    from frng.blender import scene as bscene
    from frng.blender import world

    az, el = math.radians(40.0), math.radians(25.0)
    blob = np.array([math.cos(el) * math.cos(az), math.cos(el) * math.sin(az), math.sin(el)])
    env_path = tmp_path / "blob.exr"
    envmap.write(env_path, blob_map(128, 256, blob))

    res = 64
    scene = bscene.new_scene(res, 16, 2, seed=0, transparent=False)
    bpy.ops.mesh.primitive_uv_sphere_add(segments=128, ring_count=64, radius=1.0)
    sphere = bpy.context.active_object
    sphere.data.polygons.foreach_set("use_smooth", [True] * len(sphere.data.polygons))
    mat = bpy.data.materials.new("mirror")
    mat.use_nodes = True
    bsdf = mat.node_tree.nodes["Principled BSDF"]
    bsdf.inputs["Metallic"].default_value = 1.0
    bsdf.inputs["Roughness"].default_value = 0.0
    bsdf.inputs["Base Color"].default_value = (1, 1, 1, 1)
    sphere.data.materials.append(mat)
    world.set_envmap(scene, env_path, 256)

    for cam_az, cam_el in ((10.0, 15.0), (70.0, -10.0)):
        c2w = camera.look_at(camera.spherical_to_cartesian(cam_az, cam_el, 4.0))
        K = camera.intrinsics_from_fov(40.0, res, res)
        cam = scene.camera or bscene.add_camera(scene, 40.0)
        bscene.set_camera_pose(cam, c2w)
        out = tmp_path / f"render_{cam_az:g}.exr"
        bscene.render_to(scene, out)
        rgb = bscene.read_passes(out)["rgba"][..., :3]
        expected, mask = predicted_highlight(c2w, K, res, blob)
        lum = np.where(mask, envmap.luminance(rgb), -1.0)
        got = np.array(np.unravel_index(np.argmax(lum), lum.shape))
        assert lum.max() > 5.0, "no highlight rendered"
        assert np.abs(got - expected).max() <= 1.5, f"highlight at {got}, convention predicts {expected}"
