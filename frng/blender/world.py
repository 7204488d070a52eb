"""World lighting: an equirect environment map (frng.render.envmap's convention) and sky baking.

Blender's Environment Texture node with default mapping already follows ``frng.render.envmap``'s equirect
convention (tests/test_envmap_blender.py checks it), so maps are used as written, unrotated.
"""

from __future__ import annotations

import math
from pathlib import Path

import bpy
import numpy as np

from frng.blender import scene as bscene


def _world(scene: bpy.types.Scene) -> bpy.types.World:
    if scene.world is None:
        scene.world = bpy.data.worlds.new("frng_world")
    world = scene.world
    world.use_nodes = True
    return world


def set_envmap(scene: bpy.types.Scene, path: str | Path, sample_map_resolution: int = 256) -> None:
    """Light the scene with an equirect HDR map (linear EXR/HDR), strength 1.

    Importance sampling uses a MANUAL map of ``sample_map_resolution`` (the AUTOMATIC one costs ~0.6 s per render).
    Replaces the previous map (and frees its image).
    """
    world = _world(scene)
    nt = world.node_tree
    env = nt.nodes.get("frng_env")
    if env is None:
        nt.nodes.clear()
        env = nt.nodes.new("ShaderNodeTexEnvironment")
        env.name = "frng_env"
        env.interpolation = "Linear"
        bg = nt.nodes.new("ShaderNodeBackground")
        out = nt.nodes.new("ShaderNodeOutputWorld")
        nt.links.new(env.outputs["Color"], bg.inputs["Color"])
        nt.links.new(bg.outputs["Background"], out.inputs["Surface"])
    old = env.image
    img = bpy.data.images.load(str(path), check_existing=False)
    img.colorspace_settings.name = "Linear Rec.709"
    env.image = img
    if old is not None:
        bpy.data.images.remove(old)
    world.cycles.sampling_method = "MANUAL"
    world.cycles.sample_map_resolution = int(sample_map_resolution)


def bake_sky(
    path: str | Path, model: str, sun_elevation_deg: float, turbidity: float, width: int, spp: int = 1, threads: int = 2
) -> None:
    """Render a Preetham or Hosek-Wilkie sky (sun towards +X at the given elevation) to an equirect EXR.

    A panoramic equirect camera at the origin with rotation (90, 0, -90) deg reproduces frng.render.envmap's convention.
    Writes a multilayer EXR at ``path`` (read it with :func:`frng.blender.scene.read_passes`).
    """
    scene = bscene.new_scene((width, width // 2), spp, threads, seed=0, transparent=False)
    world = _world(scene)
    nt = world.node_tree
    nt.nodes.clear()
    sky = nt.nodes.new("ShaderNodeTexSky")
    sky.sky_type = {"preetham": "PREETHAM", "hosek_wilkie": "HOSEK_WILKIE"}[model]
    el = math.radians(sun_elevation_deg)
    sky.sun_direction = (math.cos(el), 0.0, math.sin(el))
    sky.turbidity = float(turbidity)
    bg = nt.nodes.new("ShaderNodeBackground")
    out = nt.nodes.new("ShaderNodeOutputWorld")
    nt.links.new(sky.outputs["Color"], bg.inputs["Color"])
    nt.links.new(bg.outputs["Background"], out.inputs["Surface"])
    world.cycles.sampling_method = "NONE"  # nothing is lit: no importance map to build
    cam_data = bpy.data.cameras.new("pano")
    cam_data.type = "PANO"
    cam_data.panorama_type = "EQUIRECTANGULAR"
    cam = bpy.data.objects.new("pano", cam_data)
    cam.rotation_euler = (math.radians(90.0), 0.0, math.radians(-90.0))
    scene.collection.objects.link(cam)
    scene.camera = cam
    bscene.render_to(scene, path)


def ground(image: np.ndarray, albedo: float = 0.3) -> np.ndarray:
    """Darken the lower hemisphere (rows below the horizon) of a sky map: a grey ground of the given albedo.

    Blender's analytic skies continue the horizon colour below it, which lights objects from underneath as
    brightly as the horizon; a real ground reflects a fraction of it.
    """
    h = image.shape[0]
    out = image.copy()
    out[h // 2 :] *= albedo
    return out
