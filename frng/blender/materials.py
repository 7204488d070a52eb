"""Materials: the paper's mix of diffuse / specular Principled BSDFs and fur (Principled Hair BSDF).

Every material writes three AOVs the G-buffer is made of (see frng.blender.scene.AOVS):
``albedo`` (linear RGB base colour, the texture's value where textured), ``roughness`` and ``metallic`` (scalars).

:func:`sample` draws the parameters (pure numpy, recorded in meta.json); :func:`apply` builds them in Blender.
"""

from __future__ import annotations

import colorsys
import math

import bpy
import numpy as np

TEXTURE_SIZE = 256
PATTERNS = ("checker", "stripes", "dots", "noise")


def _colour(rng: np.random.Generator) -> list[float]:
    """A random linear RGB colour (HSV drawn in display space, then sRGB-decoded by a 2.2 power)."""
    h, s, v = rng.uniform(0, 1), rng.uniform(0.1, 0.9), rng.uniform(0.3, 0.95)
    return [round(float(c) ** 2.2, 5) for c in colorsys.hsv_to_rgb(h, s, v)]


def sample(rng: np.random.Generator, material_class: str, fur_strands: int) -> dict:
    """Material parameters of one object.

    diffuse:  roughness U(0.6, 1), metallic 0, image texture with p = 0.6
    specular: roughness U(0.03, 0.35), metallic U(0.8, 1) with p = 0.5 else 0, image texture with p = 0.4
    fur:      diffuse skin + hair particles (Principled Hair BSDF, colour parametrisation)
    """
    p: dict = {"class": material_class, "base_color": _colour(rng)}
    if material_class == "diffuse":
        p.update(roughness=float(rng.uniform(0.6, 1.0)), metallic=0.0, textured=bool(rng.uniform() < 0.6))
    elif material_class == "specular":
        metal = rng.uniform() < 0.5
        p.update(roughness=float(rng.uniform(0.03, 0.35)), metallic=float(rng.uniform(0.8, 1.0)) if metal else 0.0,
                 textured=bool(rng.uniform() < 0.4))
    elif material_class == "fur":
        children = 10
        p.update(roughness=1.0, metallic=0.0, textured=False, hair={
            "color": _colour(rng),
            "roughness": float(rng.uniform(0.2, 0.5)),
            "radial_roughness": float(rng.uniform(0.2, 0.5)),
            "length": float(rng.uniform(0.08, 0.15)),
            "parents": max(1, fur_strands // children),
            "children": children,
            "root_radius": 0.008,
        })
        p["base_color"] = [round(c * 0.6, 5) for c in p["hair"]["color"]]  # skin under the fur
    else:
        raise ValueError(f"unknown material class {material_class!r}")
    if p["textured"]:
        p["texture"] = {"pattern": PATTERNS[int(rng.integers(len(PATTERNS)))], "color2": _colour(rng),
                        "frequency": int(rng.integers(3, 12)), "seed": int(rng.integers(2**31))}
    return p


def texture_pixels(tex: dict, color1, size: int = TEXTURE_SIZE) -> np.ndarray:
    """A (size, size, 4) linear RGBA pattern image from two colours (generated, no downloads)."""
    y, x = np.mgrid[0:size, 0:size] / size
    f = tex["frequency"]
    if tex["pattern"] == "checker":
        m = ((np.floor(x * f) + np.floor(y * f)) % 2).astype(np.float32)
    elif tex["pattern"] == "stripes":
        m = (np.sin(2 * math.pi * f * (x + 0.3 * y)) > 0).astype(np.float32)
    elif tex["pattern"] == "dots":
        m = ((((x * f) % 1 - 0.5) ** 2 + ((y * f) % 1 - 0.5) ** 2) < 0.09).astype(np.float32)
    else:  # smooth value noise
        r = np.random.default_rng(tex["seed"])
        g = r.uniform(0, 1, (f + 1, f + 1))
        gx, gy = x * f, y * f
        i, j = gx.astype(int), gy.astype(int)
        tx, ty = gx - i, gy - j
        tx, ty = tx * tx * (3 - 2 * tx), ty * ty * (3 - 2 * ty)
        m = ((g[j, i] * (1 - tx) + g[j, i + 1] * tx) * (1 - ty) + (g[j + 1, i] * (1 - tx) + g[j + 1, i + 1] * tx) * ty)
        m = m.astype(np.float32)
    c1, c2 = np.asarray(color1, np.float32), np.asarray(tex["color2"], np.float32)
    rgb = c1 * (1 - m[..., None]) + c2 * m[..., None]
    return np.concatenate([rgb, np.ones((size, size, 1), np.float32)], -1)


def add_aov_outputs(nt, albedo_socket, roughness, metallic) -> None:
    """AOV Output nodes: albedo <- a colour socket (or RGB list); roughness, metallic <- sockets or floats."""
    for name, value, is_color in (("albedo", albedo_socket, True), ("roughness", roughness, False),
                                  ("metallic", metallic, False)):
        node = nt.nodes.new("ShaderNodeOutputAOV")
        node.aov_name = name
        sock = node.inputs["Color" if is_color else "Value"]
        if isinstance(value, bpy.types.NodeSocket):
            nt.links.new(value, sock)
        elif is_color:
            sock.default_value = list(value)[:3] + [1.0]
        else:
            sock.default_value = float(value)


def principled(name: str, p: dict) -> bpy.types.Material:
    mat = bpy.data.materials.new(name)
    mat.use_nodes = True
    nt = mat.node_tree
    bsdf = nt.nodes["Principled BSDF"]
    bsdf.inputs["Roughness"].default_value = p["roughness"]
    bsdf.inputs["Metallic"].default_value = p["metallic"]
    if p.get("textured"):
        img = bpy.data.images.new(f"{name}_tex", TEXTURE_SIZE, TEXTURE_SIZE, float_buffer=True)
        img.colorspace_settings.name = "Linear Rec.709"
        img.pixels.foreach_set(texture_pixels(p["texture"], p["base_color"]).ravel())
        img.pack()
        tex = nt.nodes.new("ShaderNodeTexImage")
        tex.image = img
        uv = nt.nodes.new("ShaderNodeUVMap")
        nt.links.new(uv.outputs["UV"], tex.inputs["Vector"])
        nt.links.new(tex.outputs["Color"], bsdf.inputs["Base Color"])
        colour = tex.outputs["Color"]
    else:
        bsdf.inputs["Base Color"].default_value = list(p["base_color"]) + [1.0]
        colour = p["base_color"]
    add_aov_outputs(nt, colour, p["roughness"], p["metallic"])
    return mat


def hair_material(name: str, h: dict) -> bpy.types.Material:
    mat = bpy.data.materials.new(name)
    mat.use_nodes = True
    nt = mat.node_tree
    nt.nodes.remove(nt.nodes["Principled BSDF"])
    hair = nt.nodes.new("ShaderNodeBsdfHairPrincipled")
    hair.parametrization = "COLOR"
    hair.inputs["Color"].default_value = list(h["color"]) + [1.0]
    hair.inputs["Roughness"].default_value = h["roughness"]
    hair.inputs["Radial Roughness"].default_value = h["radial_roughness"]
    nt.links.new(hair.outputs[0], nt.nodes["Material Output"].inputs["Surface"])
    add_aov_outputs(nt, h["color"], h["roughness"], 0.0)
    return mat


def add_fur(obj: bpy.types.Object, h: dict, seed: int) -> None:
    """Hair particles (parents x interpolated children) rendered with the hair material in slot 2."""
    mod = obj.modifiers.new("fur", "PARTICLE_SYSTEM")
    psys = mod.particle_system
    psys.seed = int(seed) % (2**31 - 1)
    s = psys.settings
    s.type = "HAIR"
    s.count = int(h["parents"])
    s.hair_length = float(h["length"])
    s.use_advanced_hair = True
    s.factor_random = 0.3 * h["length"]
    s.child_type = "INTERPOLATED"
    s.rendered_child_count = int(h["children"])
    s.child_percent = min(int(h["children"]), 2)  # viewport only
    s.roughness_2 = 0.02
    s.root_radius = 1.0
    s.tip_radius = 0.2
    s.radius_scale = float(h["root_radius"])
    s.material_slot = obj.data.materials[1].name if len(obj.data.materials) > 1 else obj.data.materials[0].name


def apply(obj: bpy.types.Object, p: dict, seed: int) -> None:
    """Give ``obj`` the material described by ``p`` (from :func:`sample`)."""
    obj.data.materials.clear()
    obj.data.materials.append(principled("frng_surface", p))
    if p["class"] == "fur":
        obj.data.materials.append(hair_material("frng_hair", p["hair"]))
        add_fur(obj, p["hair"], seed)
