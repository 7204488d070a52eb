"""Assets keep their own materials (``objects.extra[].material: own``, issue 23 item 1).

The test writes its own tiny assets (tests/asset_writers.py): a box as OBJ + MTL with a two-colour map_Kd, a
roughness map and a normal (bump) map; a box as GLB with base-colour, metallic-roughness and normal textures; a
glass GLB (KHR_materials_transmission); a PLY with vertex colours. It curates them with Blender and checks that
the G-buffer AOVs hold the textures' values and that the glass is reported in meta.json and the log.
"""

import numpy as np
import pytest
from asset_writers import halves, srgb_to_linear, write_glb, write_obj, write_ply
from data_helpers import frng, write_config

from frng.data.dataset import open_object
from frng.plan import catalog, object_files
from frng.plan import config as frng_config

RED, BLUE = (230, 40, 30), (30, 60, 220)  # sRGB bytes of the texture halves (u < 0.5: RED)
NORMAL_30 = (191, 128, 238)  # tangent-space normal (0.5, 0, 0.866): tilted 30 deg


def _assets(root):
    write_obj(
        root / "objmtl",
        "crate",
        # map_Kd names a file on the author's disk under another format (as LIBERO's MTLs do): kd.png ships
        "newmtl crate\nKd 1 1 1\nKs 0.5 0.5 0.5\nNs 250\nillum 2\nmap_Kd /home/author/Downloads/kd.jpeg\n"
        "map_Pr pr.png\n"
        "map_Bump -bm 1.0 nrm.png\n",
        {
            "kd.png": halves(RED, BLUE),
            "pr.png": halves((51, 51, 51), (204, 204, 204)),
            "nrm.png": halves(NORMAL_30, NORMAL_30),
        },
        material="crate",
    )
    # glTF: left half rough 0.2 / metal 1, right half rough 0.8 / metal 0 (G = roughness, B = metallic)
    write_glb(
        root / "pbr.glb",
        {
            "name": "pbr",
            "pbrMetallicRoughness": {
                "baseColorTexture": {"index": "bc"},
                "metallicRoughnessTexture": {"index": "mr"},
                "metallicFactor": 1.0,
                "roughnessFactor": 1.0,
            },
            "normalTexture": {"index": "n"},
        },
        {"bc": halves(RED, BLUE), "mr": halves((0, 51, 255), (0, 204, 0)), "n": halves(NORMAL_30, NORMAL_30)},
    )
    write_glb(
        root / "glass.glb",
        {
            "name": "glass",
            "pbrMetallicRoughness": {"baseColorFactor": [1, 1, 1, 1], "roughnessFactor": 0.05, "metallicFactor": 0.0},
            "extensions": {"KHR_materials_transmission": {"transmissionFactor": 1.0}},
        },
        extensions_used=["KHR_materials_transmission"],
    )
    write_ply(root / "painted.ply", rgb=(40, 200, 60))


def test_file_material_detection(tmp_path):
    _assets(tmp_path)
    write_obj(tmp_path / "plain", "bare", None)
    assert object_files.file_material(tmp_path / "objmtl" / "crate.obj") == "mtl"
    assert object_files.file_material(tmp_path / "pbr.glb") == "gltf"
    assert object_files.file_material(tmp_path / "painted.ply") == "ply"
    assert object_files.file_material(tmp_path / "plain" / "bare.obj") is None
    assert object_files.own_material_class(0.2, 0.0) == "specular"
    assert object_files.own_material_class(0.9, 0.9) == "specular"
    assert object_files.own_material_class(0.7, 0.1) == "diffuse"


def _albedo_halves(obj):
    """The object's input G-buffer, its foreground and red-texel mask, after checking that about half the texels are
    red and that the albedo matches the texture's red / blue halves."""
    g = obj.gbuffer("inputs")
    fg = g["alpha"][..., 0] > 0.99
    alb, is_red, red, blue = _halves(g, fg)
    assert 0.2 < is_red.mean() < 0.8
    assert np.median(np.abs(alb[is_red] - red), 0).max() < 0.02
    assert np.median(np.abs(alb[~is_red] - blue), 0).max() < 0.02
    return g, fg, is_red


def _halves(g, fg):
    """Foreground pixels split by which texture half their albedo shows (nearest of RED / BLUE)."""
    alb = g["albedo"][fg]
    red, blue = srgb_to_linear(RED), srgb_to_linear(BLUE)
    is_red = np.linalg.norm(alb - red, axis=1) < np.linalg.norm(alb - blue, axis=1)
    return alb, is_red, red, blue


def _tilt_deg(normal):
    """Angle between each normal and the nearest box axis (the box's faces are axis-aligned in the world)."""
    return np.degrees(np.arccos(np.clip(np.abs(normal).max(-1), -1, 1)))


@pytest.mark.blender
def test_own_materials_are_curated_with_their_aovs(tmp_path):
    assets = tmp_path / "assets"
    _assets(assets)
    cfg = write_config(
        tmp_path / "config.yaml",
        tmp_path / "results",
        objects={
            "count": 1,
            "test_count": 1,
            "sources": ["primitives"],
            "extra": [
                {"path": str(assets / "objmtl"), "split": "train", "up": "z", "licence": "CC0 (test)"},
                {"path": str(assets / "pbr.glb"), "split": "train", "up": "z"},
                {"path": str(assets / "glass.glb"), "split": "train", "up": "z"},
                {"path": str(assets / "painted.ply"), "split": "train", "class": "diffuse"},
            ],
        },
        envmaps={
            "bundled": ["studio", "city"],
            "skies": {"models": []},
            "width": 32,
            "rotations": 1,
            "test_fraction": 0.5,
        },
        render={
            "resolution": 48,
            "spp": 2,
            "extra_input_views": 0,
            "target_views": 1,
            "input_lights": 1,
            "target_lights": 1,
        },
    )
    plan = {o.id: o for o in catalog.plan(frng_config.load(cfg)).objects}
    assert all(plan[i].material == "own" for i in ("user_crate", "user_pbr", "user_glass", "user_painted"))
    assert plan["obj_0000"].material in catalog.MATERIALS  # generated classes stay
    frng("envmaps", "--config", str(cfg))
    results = tmp_path / "results"
    logs = {
        oid: frng("curate", "--config", str(cfg), "--object", oid).stdout
        for oid in ("user_crate", "user_pbr", "user_glass", "user_painted")
    }

    # OBJ + MTL: albedo = map_Kd's texels (sRGB-decoded), roughness = map_Pr's values (data: not sRGB-decoded),
    # metallic 0, normals tilted by the bump (normal) map
    obj = open_object(results, "user_crate")
    g, fg, is_red = _albedo_halves(obj)
    rough = g["roughness"][fg][:, 0]
    assert abs(np.median(rough[is_red]) - 0.2) < 0.02 and abs(np.median(rough[~is_red]) - 0.8) < 0.02
    assert np.abs(g["metallic"][fg]).max() < 1e-3
    assert abs(np.median(_tilt_deg(g["normal"][fg])) - 30.0) < 4.0
    meta = obj.meta
    assert meta["material"]["class"] == "own" and meta["material"]["unsupported"] == []
    assert meta["material_class"] in ("diffuse", "specular") and meta["licence"] == "CC0 (test)"
    assert "pr.png" in meta["material"]["colourspace_fixed"]
    relinked = meta["material"]["textures_relinked"]
    assert [r["to"].rsplit("/", 1)[-1] for r in relinked] == ["kd.png"] and "kd.jpeg" in logs["user_crate"]

    # glTF metallic-roughness: red texels rough 0.2 / metal 1, blue texels rough 0.8 / metal 0; normal map
    obj = open_object(results, "user_pbr")
    g, fg, is_red = _albedo_halves(obj)
    rough, metal = g["roughness"][fg][:, 0], g["metallic"][fg][:, 0]
    assert abs(np.median(rough[is_red]) - 0.2) < 0.02 and abs(np.median(rough[~is_red]) - 0.8) < 0.02
    assert np.median(metal[is_red]) > 0.98 and np.median(metal[~is_red]) < 0.02
    assert abs(np.median(_tilt_deg(g["normal"][fg])) - 30.0) < 4.0
    slot = obj.meta["material"]["slots"][0]
    assert slot["base_color"]["textures"] and slot["roughness"]["textures"] and slot["normal"]["textures"]
    # the class follows the documented rule on the AOV means
    assert obj.meta["material_class"] == object_files.own_material_class(float(rough.mean()), float(metal.mean()))

    # glass: reported per object in meta.json and in the rule's log, not guessed silently
    obj = open_object(results, "user_glass")
    bad = obj.meta["material"]["unsupported"]
    assert len(bad) == 1 and any("transmission" in r for r in bad[0]["reasons"])
    assert "cannot describe transmission" in logs["user_glass"]  # (the rule's log is this output)
    assert "cannot describe" not in logs["user_crate"] + logs["user_pbr"]

    # PLY vertex colours: the albedo is the colour, matte; the class comes from the config
    obj = open_object(results, "user_painted")
    g = obj.gbuffer("inputs")
    fg = g["alpha"][..., 0] > 0.99
    assert np.abs(np.median(g["albedo"][fg], 0) - srgb_to_linear((40, 200, 60))).max() < 0.02
    assert abs(np.median(g["roughness"][fg]) - 0.8) < 1e-3
    assert obj.meta["material_class"] == "diffuse"


@pytest.mark.blender
def test_builtin_meshes_keep_their_materials_when_asked(tmp_path):
    """objects.builtin_materials: own -- pybullet's duck keeps its MTL texture (duckCM.png); the bunny has none."""
    cfg = write_config(
        tmp_path / "config.yaml",
        tmp_path / "results",
        objects={
            "count": 2,
            "test_count": 0,
            "sources": ["pybullet"],
            "builtin_materials": "own",
            "extra": [{"path": str(_box(tmp_path)), "split": "test", "material": "diffuse"}],
        },
        render={"resolution": 32, "spp": 2, "target_views": 1},
    )
    plan = {o.id: o for o in catalog.plan(frng_config.load(cfg)).objects}
    assert plan["obj_0000"].mesh == "bunny.obj" and plan["obj_0000"].material != "own"  # no MTL: generated
    assert (plan["obj_0001"].mesh, plan["obj_0001"].material) == ("duck.obj", "own")
    frng("envmaps", "--config", str(cfg))
    frng("curate", "--config", str(cfg), "--object", "obj_0001")
    obj = open_object(tmp_path / "results", "obj_0001")
    slot = obj.meta["material"]["slots"][0]
    assert slot["base_color"]["textures"][0].endswith("duckCM.png") and "COLLADA" in obj.meta["licence"]
    g = obj.gbuffer("inputs")
    fg = g["alpha"][..., 0] > 0.99
    tex = srgb_to_linear(
        np.asarray(
            __import__("PIL.Image").Image.open(object_files.pybullet_data_dir() / "duckCM.png").convert("RGB")
        ).reshape(-1, 3)
    )
    # the duck is yellow with an orange beak: every albedo pixel lies inside the texture's colour range
    alb = g["albedo"][fg]
    assert (alb >= tex.min(0) - 0.02).all() and (alb <= tex.max(0) + 0.02).all()
    assert alb[:, 0].mean() > 2 * alb[:, 2].mean()  # yellow, not the generated palette's grey-blue


def _box(tmp_path):
    return write_obj(tmp_path / "plainbox", "plainbox", None)


def _adopted(path, edit=None):
    """(object, adopt()'s description) of the file at ``path`` imported into an empty Blender scene, ``edit(obj)``
    applied before adopting."""
    import bpy

    from frng.blender import materials, objects

    bpy.ops.wm.read_factory_settings(use_empty=True)
    obj = objects.import_file(path, keep_materials=True)
    if edit:
        edit(obj)
    return obj, materials.adopt(obj)


@pytest.mark.blender
def test_what_the_aovs_cannot_describe_is_named(tmp_path):
    """adopt() names emission, transparency, clear coat, a custom node tree and a missing texture per slot; a
    plain textured material names nothing."""

    from frng.blender import materials

    write_glb(
        tmp_path / "lamp.glb",
        {
            "name": "lamp",
            "emissiveFactor": [1.0, 0.8, 0.2],
            "pbrMetallicRoughness": {"baseColorFactor": [1, 1, 1, 0.5]},
            "alphaMode": "BLEND",
        },
    )
    write_glb(
        tmp_path / "coat.glb",
        {"name": "coat", "extensions": {"KHR_materials_clearcoat": {"clearcoatFactor": 1}}},
        extensions_used=["KHR_materials_clearcoat"],
    )
    write_obj(tmp_path / "lost", "lost", "newmtl lost\nKd 1 1 1\nmap_Kd nowhere.png\n", material="lost")
    write_obj(tmp_path / "fine", "fine", "newmtl fine\nKd 0.5 0.2 0.1\nNs 100\n", material="fine")

    def reasons(path, edit=None):
        return [r for bad in _adopted(path, edit)[1]["unsupported"] for r in bad["reasons"]]

    def emission_shader(obj):  # a node tree whose surface is not a Principled BSDF
        nt = obj.data.materials[0].node_tree
        em = nt.nodes.new("ShaderNodeEmission")
        nt.links.new(em.outputs[0], materials._active_output(nt).inputs["Surface"])

    got = reasons(tmp_path / "lamp.glb")
    assert any("emission" in r for r in got) and any("transparency" in r for r in got)
    assert any("clear coat" in r for r in reasons(tmp_path / "coat.glb"))
    assert any("missing texture" in r and "nowhere.png" in r for r in reasons(tmp_path / "lost" / "lost.obj"))
    got = reasons(tmp_path / "fine" / "fine.obj", emission_shader)
    assert any("custom node tree (surface is ShaderNodeEmission" in r for r in got)
    assert reasons(tmp_path / "fine" / "fine.obj") == []


@pytest.mark.blender
def test_an_opaque_ior_of_one_is_given_a_reflection(tmp_path):
    """An MTL's ``Ni 1`` (Wavefront: the refraction index of transparent illumination models only) becomes an IOR
    of 1 in Blender's importer, which reflects nothing; adopt() sets DEFAULT_IOR and records it. An MTL without
    ``Ni`` keeps the importer's IOR, and a glass (transmission) keeps its own."""

    from frng.blender import materials

    write_obj(
        tmp_path / "book",
        "book",
        "newmtl book\nKd 0.5 0.2 0.1\nKs 0.5 0.5 0.5\nNs 96\nNi 1.0\nillum 2\n",
        material="book",
    )
    write_obj(tmp_path / "plain", "plain", "newmtl plain\nKd 0.5 0.2 0.1\nNs 96\n", material="plain")

    def adopt(path, edit=None):
        obj, info = _adopted(path, edit)
        bsdf = next(n for n in obj.data.materials[0].node_tree.nodes if n.bl_idname == "ShaderNodeBsdfPrincipled")
        return info, float(bsdf.inputs["IOR"].default_value)

    info, ior = adopt(tmp_path / "book" / "book.obj")
    assert ior == pytest.approx(materials.DEFAULT_IOR)
    assert info["ior_fixed"] == [{"slot": 0, "material": "book", "change": "IOR 1 -> 1.5"}]
    info, ior = adopt(tmp_path / "plain" / "plain.obj")
    assert info["ior_fixed"] == [] and ior > 1.0

    def glass(obj):
        bsdf = next(n for n in obj.data.materials[0].node_tree.nodes if n.bl_idname == "ShaderNodeBsdfPrincipled")
        bsdf.inputs["Transmission Weight"].default_value = 1.0

    info, ior = adopt(tmp_path / "book" / "book.obj", glass)
    assert info["ior_fixed"] == [] and ior == pytest.approx(1.0)
