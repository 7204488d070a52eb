"""Materials: the paper's mix of diffuse / specular Principled BSDFs and fur (Principled Hair BSDF).

Every material writes three AOVs the G-buffer is made of (see frng.blender.scene.AOVS):
``albedo`` (linear RGB base colour, the texture's value where textured), ``roughness`` and ``metallic`` (scalars).

:func:`sample` draws the parameters (pure numpy, recorded in meta.json); :func:`apply` builds them in Blender.
"""

from __future__ import annotations

import colorsys
import math
from pathlib import Path

import bpy
import numpy as np

TEXTURE_SIZE = 256
# A texture the importer could not load is looked for in the asset's folders under these suffixes (see relink).
IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".tga", ".bmp", ".tif", ".tiff", ".exr", ".hdr", ".webp")
PATTERNS = ("checker", "stripes", "dots", "noise")
FUR_POINTS = 6  # control points per strand (Catmull-Rom curves)
FUR_ROOT_RADIUS = 0.004  # strand radius at the root / tip (world units; the object fits the unit sphere)
FUR_TIP_RADIUS = 0.0008
FUR_TILT = 0.8  # random tilt of a strand away from the surface normal (per axis, uniform)
FUR_WAVE = 0.12  # per-point jitter, as a fraction of the strand length, growing towards the tip


def _colour(rng: np.random.Generator) -> list[float]:
    """A random linear RGB colour (HSV drawn in display space, then sRGB-decoded by a 2.2 power)."""
    h, s, v = rng.uniform(0, 1), rng.uniform(0.1, 0.9), rng.uniform(0.3, 0.95)
    return [round(float(c) ** 2.2, 5) for c in colorsys.hsv_to_rgb(h, s, v)]


def sample(rng: np.random.Generator, material_class: str, fur_strands: int) -> dict:
    """Material parameters of one object.

    diffuse:  roughness U(0.6, 1), metallic 0, image texture with p = 0.6
    specular: roughness U(0.03, 0.35), metallic U(0.8, 1) with p = 0.5 else 0, image texture with p = 0.4
    fur:      diffuse skin + ``fur_strands`` hair strands (Principled Hair BSDF, colour parametrisation), see
              :func:`add_fur`
    """
    p: dict = {"class": material_class, "base_color": _colour(rng)}
    if material_class == "diffuse":
        p.update(roughness=float(rng.uniform(0.6, 1.0)), metallic=0.0, textured=bool(rng.uniform() < 0.6))
    elif material_class == "specular":
        metal = rng.uniform() < 0.5
        p.update(
            roughness=float(rng.uniform(0.03, 0.35)),
            metallic=float(rng.uniform(0.8, 1.0)) if metal else 0.0,
            textured=bool(rng.uniform() < 0.4),
        )
    elif material_class == "fur":
        p.update(
            roughness=1.0,
            metallic=0.0,
            textured=False,
            hair={
                "color": _colour(rng),
                "roughness": float(rng.uniform(0.2, 0.5)),
                "radial_roughness": float(rng.uniform(0.2, 0.5)),
                "length": float(rng.uniform(0.08, 0.15)),
                "strands": int(fur_strands),
                "points": FUR_POINTS,
                "root_radius": FUR_ROOT_RADIUS,
                "tip_radius": FUR_TIP_RADIUS,
            },
        )
        p["base_color"] = [round(c * 0.6, 5) for c in p["hair"]["color"]]  # skin under the fur
    else:
        raise ValueError(f"unknown material class {material_class!r}")
    if p["textured"]:
        p["texture"] = {
            "pattern": PATTERNS[int(rng.integers(len(PATTERNS)))],
            "color2": _colour(rng),
            "frequency": int(rng.integers(3, 12)),
            "seed": int(rng.integers(2**31)),
        }
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
        m = (g[j, i] * (1 - tx) + g[j, i + 1] * tx) * (1 - ty) + (g[j + 1, i] * (1 - tx) + g[j + 1, i + 1] * tx) * ty
        m = m.astype(np.float32)
    c1, c2 = np.asarray(color1, np.float32), np.asarray(tex["color2"], np.float32)
    rgb = c1 * (1 - m[..., None]) + c2 * m[..., None]
    return np.concatenate([rgb, np.ones((size, size, 1), np.float32)], -1)


def add_aov_outputs(nt, albedo_socket, roughness, metallic) -> None:
    """AOV Output nodes: albedo <- a colour socket (or RGB list); roughness, metallic <- sockets or floats."""
    for name, value, is_color in (
        ("albedo", albedo_socket, True),
        ("roughness", roughness, False),
        ("metallic", metallic, False),
    ):
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


def _surface_samples(obj: bpy.types.Object, n: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """``n`` points (n, 3) uniformly distributed by area over the evaluated (rendered) surface of ``obj`` and their
    shading normals (n, 3): corner normals interpolated, so flat faces give flat normals."""
    dg = bpy.context.evaluated_depsgraph_get()
    ev = obj.evaluated_get(dg)
    me = ev.to_mesh()
    try:
        me.calc_loop_triangles()
        nt = len(me.loop_triangles)
        tri_v = np.empty(nt * 3, np.int64)
        tri_l = np.empty(nt * 3, np.int64)
        me.loop_triangles.foreach_get("vertices", tri_v)
        me.loop_triangles.foreach_get("loops", tri_l)
        co = np.empty(len(me.vertices) * 3, np.float64)
        me.vertices.foreach_get("co", co)
        cn = np.empty(len(me.loops) * 3, np.float64)
        me.corner_normals.foreach_get("vector", cn)
    finally:
        ev.to_mesh_clear()
    tri = co.reshape(-1, 3)[tri_v.reshape(-1, 3)]  # (T, 3 corners, 3)
    nrm = cn.reshape(-1, 3)[tri_l.reshape(-1, 3)]
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    if not np.isfinite(area).all() or area.sum() <= 0:
        raise ValueError(f"{obj.name}: no surface area to grow fur on")
    cdf = np.cumsum(area)
    face = np.minimum(np.searchsorted(cdf, rng.uniform(0.0, cdf[-1], n), side="right"), len(area) - 1)
    r1, r2 = np.sqrt(rng.uniform(size=n)), rng.uniform(size=n)
    w = np.stack([1 - r1, r1 * (1 - r2), r1 * r2], 1)[..., None]  # uniform barycentrics
    points = (tri[face] * w).sum(1)
    normals = (nrm[face] * w).sum(1)
    length = np.linalg.norm(normals, axis=1, keepdims=True)
    fallback = np.cross(tri[face, 1] - tri[face, 0], tri[face, 2] - tri[face, 0])
    normals = np.where(
        length > 1e-8,
        normals / np.maximum(length, 1e-8),
        fallback / np.maximum(np.linalg.norm(fallback, axis=1, keepdims=True), 1e-12),
    )
    return points, normals


def fur_strands(obj: bpy.types.Object, h: dict, seed: int) -> np.ndarray:
    """Control points (strands, points, 3) of the fur on ``obj``: roots uniform by area on the rendered surface,
    straight along the tilted shading normal, length ``h["length"]`` x U(0.8, 1.2), slightly wavy towards the tip.

    Pure numpy from ``seed``: Blender's hair particle distribution is not reproducible run to run on many meshes
    (UV spheres, cones, cylinders: parent roots land on different faces in every process, whatever the seed and
    thread count), so the strands are generated here and handed to Blender as plain curves.
    """
    rng = np.random.default_rng(np.random.SeedSequence(int(seed), spawn_key=(0xF0,)))
    n, k = int(h["strands"]), int(h["points"])
    roots, normals = _surface_samples(obj, n, rng)
    direction = normals + FUR_TILT * rng.uniform(-1.0, 1.0, (n, 3))
    direction /= np.maximum(np.linalg.norm(direction, axis=1, keepdims=True), 1e-12)
    length = float(h["length"]) * rng.uniform(0.8, 1.2, (n, 1, 1))
    t = np.linspace(0.0, 1.0, k)[None, :, None]
    wave = FUR_WAVE * rng.normal(0.0, 1.0, (n, k, 3)) * t
    pts = roots[:, None] + length * (t * direction[:, None] + wave)
    return pts.astype(np.float32)


def add_fur(obj: bpy.types.Object, h: dict, seed: int) -> bpy.types.Object:
    """A hair-curves object beside ``obj`` holding :func:`fur_strands`, rendered with the hair material
    (Cycles curves; radius tapering linearly from ``root_radius`` to ``tip_radius``). Returns the new object."""
    pts = fur_strands(obj, h, seed)
    n, k = pts.shape[:2]
    curves = bpy.data.hair_curves.new("frng_fur")
    curves.add_curves([k] * n)
    curves.position_data.foreach_set("vector", pts.ravel())
    radius = curves.attributes.get("radius") or curves.attributes.new("radius", "FLOAT", "POINT")
    r = np.linspace(float(h["root_radius"]), float(h["tip_radius"]), k, dtype=np.float32)
    radius.data.foreach_set("value", np.tile(r, n))
    curves.materials.append(hair_material("frng_hair", h))
    fur = bpy.data.objects.new("frng_fur", curves)
    fur.matrix_world = obj.matrix_world.copy()
    for col in obj.users_collection:
        col.objects.link(fur)
    return fur


def apply(obj: bpy.types.Object, p: dict, seed: int) -> None:
    """Give ``obj`` the material described by ``p`` (from :func:`sample`)."""
    obj.data.materials.clear()
    obj.data.materials.append(principled("frng_surface", p))
    if p["class"] == "fur":
        add_fur(obj, p["hair"], seed)


# -- assets' own materials (objects.extra[].material: own) ----------------------------------------------------------

PLY_ROUGHNESS = 0.8  # a PLY's vertex colours carry no finish: matte dielectric
NEUTRAL = {"base_color": [0.5, 0.5, 0.5], "roughness": 0.5, "metallic": 0.0}
DATA_SOCKETS = ("Roughness", "Metallic", "Alpha")  # Principled inputs whose textures hold data, not colour


def _upstream(socket, kind: str | None = None, seen=None) -> list:
    """Nodes feeding ``socket`` (recursively), optionally only those of bl_idname ``kind``."""
    seen = set() if seen is None else seen
    out = []
    for link in socket.links:
        node = link.from_node
        if node.name in seen:
            continue
        seen.add(node.name)
        if kind is None or node.bl_idname == kind:
            out.append(node)
        for s in node.inputs:
            out += _upstream(s, kind, seen)
    return out


def _texture_names(socket) -> list[str]:
    return [n.image.filepath or n.image.name for n in _upstream(socket, "ShaderNodeTexImage") if n.image]


def _describe(socket) -> object:
    """A socket's value for meta.json: its constant, or what feeds it (textures, vertex colours, nodes)."""
    if not socket.is_linked:
        v = socket.default_value
        return [round(float(x), 5) for x in v][:3] if hasattr(v, "__len__") else round(float(v), 5)
    nodes = _upstream(socket)
    d = {"linked": sorted({n.bl_idname.replace("ShaderNode", "") for n in nodes})}
    tex = _texture_names(socket)
    if tex:
        d["textures"] = tex
    if any(n.bl_idname in ("ShaderNodeVertexColor", "ShaderNodeAttribute") for n in nodes):
        d["vertex_colors"] = True
    return d


def _active_output(nt):
    outs = [n for n in nt.nodes if n.bl_idname == "ShaderNodeOutputMaterial"]
    for n in outs:
        if n.is_active_output and n.target in ("ALL", "CYCLES"):
            return n
    return outs[0] if outs else None


def _neutral(name: str) -> bpy.types.Material:
    return principled(name, {**NEUTRAL, "textured": False})


def _vertex_colour_material(name: str, layer: str) -> bpy.types.Material:
    mat = bpy.data.materials.new(name)
    mat.use_nodes = True
    nt = mat.node_tree
    bsdf = nt.nodes["Principled BSDF"]
    col = nt.nodes.new("ShaderNodeVertexColor")
    col.layer_name = layer
    nt.links.new(col.outputs["Color"], bsdf.inputs["Base Color"])
    bsdf.inputs["Roughness"].default_value = PLY_ROUGHNESS
    bsdf.inputs["Metallic"].default_value = 0.0
    return mat


def _unsupported_inputs(bsdf) -> list[str]:
    """What a Principled BSDF does that the albedo / roughness / metallic / normal G-buffer cannot describe."""

    def active(name: str, threshold: float = 0.0) -> bool:
        s = bsdf.inputs.get(name)
        return s is not None and (s.is_linked or float(s.default_value) > threshold)

    reasons = []
    if active("Transmission Weight"):
        reasons.append("transmission (glass)")
    em = bsdf.inputs["Emission Color"]
    if active("Emission Strength") and (em.is_linked or max(em.default_value[:3]) > 0):
        reasons.append("emission")
    alpha = bsdf.inputs["Alpha"]
    if alpha.is_linked or alpha.default_value < 1.0:
        reasons.append("transparency (alpha " + ("texture" if alpha.is_linked else f"{alpha.default_value:.3g}") + ")")
    for name, what in (("Coat Weight", "clear coat"), ("Sheen Weight", "sheen"), ("Subsurface Weight", "subsurface")):
        if active(name):
            reasons.append(what)
    return reasons


# the IOR an opaque surface gets where its file's IOR reflects nothing (:func:`_reflective_ior`); Blender's default
DEFAULT_IOR = 1.5


def _reflective_ior(bsdf) -> str | None:
    """An opaque Principled BSDF with IOR <= 1 reflects nothing (its Fresnel F0 = ((n - 1) / (n + 1))^2 = 0):
    Blender's OBJ importer copies the MTL's ``Ni`` into the IOR, but Wavefront's ``Ni`` is the refraction index
    of the transparent illumination models only (``illum`` 4-7); exporters write ``Ni 1`` for opaque materials
    whose ``Ks`` and ``Ns`` ask for highlights (LIBERO's books and wine bottle: Ks 0.5, Ns 96-250, Ni 1). Such an
    IOR is set to :data:`DEFAULT_IOR`; a transmissive surface keeps its own. Returns what was changed, or None."""
    ior = bsdf.inputs.get("IOR")
    trans = bsdf.inputs.get("Transmission Weight")
    if ior is None or ior.is_linked or float(ior.default_value) > 1.0 + 1e-6:
        return None
    if trans is not None and (trans.is_linked or float(trans.default_value) > 0.0):
        return None
    old = float(ior.default_value)
    ior.default_value = DEFAULT_IOR
    return f"IOR {old:g} -> {DEFAULT_IOR:g}"


def _data_colourspace(bsdf, nt) -> list[str]:
    """Image textures feeding only data inputs (roughness, metallic, alpha, normal / bump maps) are read as
    Non-Color (Blender's OBJ importer loads map_Pr / map_Pm / bump maps as sRGB); returns the images changed."""
    colour = {n.image.name for n in _upstream(bsdf.inputs["Base Color"], "ShaderNodeTexImage") if n.image}
    data_sockets = [bsdf.inputs[s] for s in DATA_SOCKETS]
    for node in _upstream(bsdf.inputs["Normal"]):
        if node.bl_idname in ("ShaderNodeNormalMap", "ShaderNodeBump"):
            data_sockets += [s for s in node.inputs if s.name in ("Color", "Height")]
    changed = []
    for sock in data_sockets:
        for n in _upstream(sock, "ShaderNodeTexImage"):
            img = n.image
            if img is not None and img.name not in colour and img.colorspace_settings.name != "Non-Color":
                img.colorspace_settings.name = "Non-Color"
                changed.append(img.name)
    return sorted(set(changed))


def find_texture(ref: str, search_dirs) -> Path | None:
    """Where a texture reference that does not load (``ref``: the path the file names, often one from the author's
    machine, or a file shipped under another image format) can be found: in each of ``search_dirs`` (in order), the
    same base name, then the same stem with any of :data:`IMAGE_SUFFIXES`. None when nothing matches. A candidate
    that resolves outside its folder (a symlink out; :func:`frng.confine.is_inside`) is not taken."""
    from frng.confine import is_inside

    name = ref.replace("\\", "/").rsplit("/", 1)[-1]
    if not name:
        return None
    stem = name.rsplit(".", 1)[0] if "." in name else name
    for d in search_dirs:
        d = Path(d)
        for cand in [d / name, *(d / f"{stem}{suffix}" for suffix in IMAGE_SUFFIXES)]:
            if cand.is_file() and is_inside(cand, d):
                return cand
    return None


def _relink(nt, search_dirs, relinked: list) -> None:
    """Point each image node of ``nt`` whose image did not load at :func:`find_texture`'s file; each fix is
    appended to ``relinked`` as ``{"from", "to"}`` (an image shared by several nodes once)."""
    for n in nt.nodes:
        if n.bl_idname != "ShaderNodeTexImage" or n.image is None or n.image.size[0] != 0:
            continue
        ref = n.image.filepath or n.image.name
        found = find_texture(bpy.path.abspath(ref), search_dirs)
        if found is None:
            continue
        n.image.filepath = str(found)
        n.image.reload()
        if n.image.size[0] != 0:
            relinked.append({"from": ref, "to": str(found)})


def adopt(obj: bpy.types.Object, search_dirs=()) -> dict:
    """Keep ``obj``'s own materials (imported from the file) and make them write the G-buffer AOVs from their
    own inputs: ``albedo`` <- whatever feeds the Principled BSDF's Base Color (texture x factor x vertex colour
    as the importer built it), ``roughness`` / ``metallic`` <- what feeds those inputs (the glTF
    metallic-roughness texture's G / B channels x factors, MTL Ns / Pr / Pm / map_Pr / map_Pm); the normal pass
    carries normal and bump maps (Cycles writes the shading normal). Data textures are switched to Non-Color.

    A PLY's vertex colours (no material in the file) become a Principled base colour (roughness
    :data:`PLY_ROUGHNESS`, metallic 0). An empty slot gets a neutral grey (reported).

    What the AOVs cannot describe is reported, never guessed silently: a surface that is not a Principled BSDF
    (custom node trees: AOVs from the tree's only Principled BSDF if it has one, else the neutral constants),
    transmission, emission, transparency, clear coat, sheen, subsurface, volume, displacement, missing textures.
    A texture that does not load is first looked for in ``search_dirs`` (the asset's folders; rule:
    :func:`find_texture`): LIBERO's MTLs, for one, name ``.jpeg`` files from the author's disk that ship as ``.png``
    beside the mesh. What was found that way is listed under ``textures_relinked``.

    An opaque surface whose IOR is 1 (no reflection: an MTL's ``Ni 1``) gets :data:`DEFAULT_IOR`
    (:func:`_reflective_ior`), listed under ``ior_fixed``.

    Returns the description recorded in meta.json's ``material``: ``{"class": "own", "slots": [...],
    "unsupported": [{"slot", "material", "reasons"}], "colourspace_fixed": [...], "textures_relinked": [...],
    "ior_fixed": [{"slot", "material", "change"}]}``.
    """
    me = obj.data
    info: dict = {
        "class": "own",
        "slots": [],
        "unsupported": [],
        "colourspace_fixed": [],
        "textures_relinked": [],
        "ior_fixed": [],
    }
    if not len(me.materials) or all(m is None for m in me.materials):
        layers = list(me.color_attributes.keys())
        me.materials.clear()
        if layers:
            me.materials.append(_vertex_colour_material("frng_vertex_colours", layers[0]))
            info["source"] = f"vertex colours ({layers[0]}), roughness {PLY_ROUGHNESS}, metallic 0"
        else:
            me.materials.append(None)
    for i, mat in enumerate(list(me.materials)):
        reasons: list[str] = []
        if mat is None or not mat.use_nodes:
            reasons.append(
                "no material (neutral grey assigned)"
                if mat is None
                else "material without nodes (neutral grey assigned)"
            )
            mat = _neutral(f"frng_neutral_{i}")
            me.materials[i] = mat
        nt = mat.node_tree
        out = _active_output(nt)
        surface = out.inputs["Surface"].links[0].from_node if out and out.inputs["Surface"].is_linked else None
        bsdf = surface if surface is not None and surface.bl_idname == "ShaderNodeBsdfPrincipled" else None
        if bsdf is None:
            found = [n for n in nt.nodes if n.bl_idname == "ShaderNodeBsdfPrincipled"]
            kind = surface.bl_idname if surface is not None else "nothing"
            if len(found) == 1:
                bsdf = found[0]
                reasons.append(f"custom node tree (surface is {kind}; AOVs from its Principled BSDF's inputs)")
            else:
                reasons.append(f"custom node tree (surface is {kind}; AOVs hold neutral constants)")
        if out is not None:
            for name in ("Volume", "Displacement"):
                if out.inputs[name].is_linked:
                    reasons.append(name.lower())
        _relink(nt, search_dirs, info["textures_relinked"])
        for n in nt.nodes:
            if n.bl_idname == "ShaderNodeTexImage" and n.image is not None and n.image.size[0] == 0:  # not loadable
                reasons.append(f"missing texture {n.image.filepath or n.image.name}")
        slot: dict = {"slot": i, "name": mat.name}
        if bsdf is not None:
            reasons += _unsupported_inputs(bsdf)
            info["colourspace_fixed"] += _data_colourspace(bsdf, nt)
            change = _reflective_ior(bsdf)
            if change:
                info["ior_fixed"].append({"slot": i, "material": mat.name, "change": change})
            sockets = {k: bsdf.inputs[k] for k in ("Base Color", "Roughness", "Metallic")}
            aov = [
                s.links[0].from_socket
                if s.is_linked
                else (list(s.default_value) if k == "Base Color" else float(s.default_value))
                for k, s in sockets.items()
            ]
            slot.update(
                base_color=_describe(sockets["Base Color"]),
                roughness=_describe(sockets["Roughness"]),
                metallic=_describe(sockets["Metallic"]),
                normal=_describe(bsdf.inputs["Normal"]) if bsdf.inputs["Normal"].is_linked else None,
            )
        else:
            aov = [NEUTRAL["base_color"], NEUTRAL["roughness"], NEUTRAL["metallic"]]
        add_aov_outputs(nt, *aov)
        info["slots"].append(slot)
        if reasons:
            info["unsupported"].append({"slot": i, "material": mat.name, "reasons": reasons})
    info["colourspace_fixed"] = sorted(set(info["colourspace_fixed"]))
    return info
