"""Objects: import users'/pybullet meshes, build primitives and procedural shapes, normalise.

Every builder returns one mesh object in world Z-up, normalised so its vertices fit the sphere of radius
``radius`` (1 by default) at the origin: centre = bounding-box centre, scale = radius / max vertex distance.
:func:`load` also returns ``file_to_world`` (4, 4): world point = file_to_world @ (file point, 1), for tests
and users who need to locate their own mesh's features in the renders.

Meshes without UVs get a spherical projection UV map so image textures work on every object.
"""

from __future__ import annotations

import math
from pathlib import Path

import bpy
import numpy as np
from mathutils import Matrix

from frng.blender import scene as bscene

Y_UP_TO_Z_UP = np.array([[1, 0, 0, 0], [0, 0, -1, 0], [0, 1, 0, 0], [0, 0, 0, 1]], dtype=np.float64)  # +90 deg about X


class MeshError(RuntimeError):
    """A mesh failed to load or is degenerate; the message names the file/object."""


# -- helpers --------------------------------------------------------------------------------------------


def vertices(obj: bpy.types.Object) -> np.ndarray:
    """Vertex positions (N, 3) in the object's local frame."""
    me = obj.data
    co = np.empty(len(me.vertices) * 3, dtype=np.float64)
    me.vertices.foreach_get("co", co)
    return co.reshape(-1, 3)


def normalisation(points: np.ndarray, radius: float = 1.0) -> np.ndarray:
    """(4, 4) that moves the bounding-box centre of ``points`` (N, 3) to the origin and scales them into ``radius``."""
    centre = 0.5 * (points.min(0) + points.max(0))
    r = float(np.linalg.norm(points - centre, axis=1).max())
    if not np.isfinite(r) or r <= 1e-12:
        raise MeshError("mesh is degenerate (all vertices at one point)")
    m = np.eye(4)
    m[:3, :3] *= radius / r
    m[:3, 3] = -centre * radius / r
    return m


def transform_mesh(obj: bpy.types.Object, m: np.ndarray) -> None:
    obj.data.transform(Matrix(np.asarray(m).tolist()))
    obj.data.update()


def ensure_uvs(obj: bpy.types.Object) -> bool:
    """Give a mesh without UVs a spherical projection UV map; returns True if it already had UVs."""
    me = obj.data
    if len(me.uv_layers):
        return True
    uv = me.uv_layers.new(name="UVMap")
    n = len(me.loops)
    vidx = np.empty(n, dtype=np.int64)
    me.loops.foreach_get("vertex_index", vidx)
    p = vertices(obj)[vidx]
    r = np.linalg.norm(p, axis=1) + 1e-12
    uvs = np.stack(
        [0.5 + np.arctan2(p[:, 1], p[:, 0]) / (2 * math.pi), 1.0 - np.arccos(np.clip(p[:, 2] / r, -1, 1)) / math.pi], 1
    )
    uv.data.foreach_set("uv", uvs.astype(np.float32).ravel())
    return False


def _mesh_object(name: str, verts: np.ndarray, faces: list) -> bpy.types.Object:
    me = bpy.data.meshes.new(name)
    me.from_pydata([tuple(v) for v in np.asarray(verts, dtype=np.float64)], [], faces)
    me.validate()
    me.update()
    obj = bpy.data.objects.new(name, me)
    bpy.context.scene.collection.objects.link(obj)
    return obj


def _uv_sphere(segments: int, rings: int) -> bpy.types.Object:
    """A unit UV sphere (quads, triangle fans at the poles) with a latitude/longitude UV map, built in numpy.

    Blender's own ``primitive_uv_sphere_add`` (4.5) orders its faces and loops differently in every run (the
    vertices agree), which moves everything sampled per face -- fur roots above all -- between runs.
    """
    theta = np.linspace(0, math.pi, rings + 1)[1:-1]  # polar angle of the inner rings
    phi = np.linspace(0, 2 * math.pi, segments, endpoint=False)
    ring_verts = np.stack(
        [
            np.sin(theta)[:, None] * np.cos(phi),
            np.sin(theta)[:, None] * np.sin(phi),
            np.broadcast_to(np.cos(theta)[:, None], (rings - 1, segments)),
        ],
        -1,
    ).reshape(-1, 3)
    verts = np.concatenate([ring_verts, [[0, 0, 1], [0, 0, -1]]])
    top, bottom = len(ring_verts), len(ring_verts) + 1
    faces, uvs = [], []
    for i in range(segments):
        i1 = (i + 1) % segments
        u0, u1 = i / segments, (i + 1) / segments
        faces.append((top, i, i1))  # counter-clockwise seen from outside
        uvs += [((u0 + u1) / 2, 1.0), (u0, 1 - 1 / rings), (u1, 1 - 1 / rings)]
        for j in range(rings - 2):
            a, b = j * segments, (j + 1) * segments
            faces.append((a + i, b + i, b + i1, a + i1))
            v0, v1 = 1 - (j + 1) / rings, 1 - (j + 2) / rings
            uvs += [(u0, v0), (u0, v1), (u1, v1), (u1, v0)]
        last = (rings - 2) * segments
        faces.append((bottom, last + i1, last + i))
        uvs += [((u0 + u1) / 2, 0.0), (u1, 1 / rings), (u0, 1 / rings)]
    obj = _mesh_object("frng_uv_sphere", verts, faces)
    uv = obj.data.uv_layers.new(name="UVMap")
    uv.data.foreach_set("uv", np.asarray(uvs, dtype=np.float32).ravel())
    return obj


def _shade_smooth(obj: bpy.types.Object, smooth: bool = True) -> None:
    vals = np.full(len(obj.data.polygons), smooth, dtype=bool)
    obj.data.polygons.foreach_set("use_smooth", vals)


def _select_only(objs) -> None:
    for o in bpy.context.scene.objects:
        o.select_set(False)
    for o in objs:
        o.select_set(True)
    bpy.context.view_layer.objects.active = objs[0]


# -- file import ----------------------------------------------------------------------------------------

_PLY_TYPES = {
    "char": "i1",
    "int8": "i1",
    "uchar": "u1",
    "uint8": "u1",
    "short": "i2",
    "int16": "i2",
    "ushort": "u2",
    "uint16": "u2",
    "int": "i4",
    "int32": "i4",
    "uint": "u4",
    "uint32": "u4",
    "float": "f4",
    "float32": "f4",
    "double": "f8",
    "float64": "f8",
}


def _first_nonfinite(values, where) -> str | None:
    """``where(i)`` of the first row of ``values`` (N, 3) holding a NaN/inf, else None."""
    bad = ~np.isfinite(np.asarray(values, dtype=np.float64)).all(axis=1)
    return where(int(np.argmax(bad))) if bad.any() else None


def _nonfinite_obj(text: str) -> str | None:
    for no, line in enumerate(text.splitlines(), 1):
        parts = line.split()
        if len(parts) >= 4 and parts[0] == "v":
            try:
                xyz = [float(t) for t in parts[1:4]]
            except ValueError:
                continue  # not a number at all: the importer's business
            if not all(math.isfinite(c) for c in xyz):
                return f"line {no} ({line.strip()!r})"
    return None


def _nonfinite_stl(data: bytes) -> str | None:
    n = int.from_bytes(data[80:84], "little") if len(data) >= 84 else -1
    if n >= 0 and len(data) == 84 + 50 * n:  # binary STL
        tris = np.frombuffer(
            data, dtype=np.dtype([("n", "<f4", 3), ("v", "<f4", (3, 3)), ("a", "<u2")]), count=n, offset=84
        )
        return _first_nonfinite(tris["v"].reshape(-1, 3), lambda i: f"triangle {i // 3 + 1}")
    for no, line in enumerate(data.decode("utf-8", "replace").splitlines(), 1):
        parts = line.split()
        if len(parts) >= 4 and parts[0] == "vertex":
            try:
                xyz = [float(t) for t in parts[1:4]]
            except ValueError:
                continue
            if not all(math.isfinite(c) for c in xyz):
                return f"line {no} ({line.strip()!r})"
    return None


def _nonfinite_ply(data: bytes) -> str | None:
    """Checks the vertex x, y, z of PLY files whose first element is ``vertex`` with scalar properties (the
    usual layout); other layouts are left to the check after import."""
    end = data.find(b"end_header")
    if not data.startswith(b"ply") or end < 0:
        return None
    body = data.index(b"\n", end) + 1
    header = data[:end].decode("ascii", "replace").splitlines()
    fmt, elements = None, []
    for line in header:
        parts = line.split()
        if parts[:1] == ["format"] and len(parts) >= 2:
            fmt = parts[1]
        elif parts[:1] == ["element"] and len(parts) >= 3:
            elements.append((parts[1], int(parts[2]), []))
        elif parts[:1] == ["property"] and elements and len(parts) >= 3:
            elements[-1][2].append(parts[1:])
    if not elements or elements[0][0] != "vertex":
        return None
    _, count, props = elements[0]
    if any(p[0] == "list" or p[0] not in _PLY_TYPES for p in props):
        return None
    names = [p[1] for p in props]
    if not all(c in names for c in "xyz"):
        return None
    cols = [names.index(c) for c in "xyz"]
    if fmt == "ascii":
        rows = data[body:].decode("ascii", "replace").splitlines()[:count]
        try:
            xyz = [[float(r.split()[c]) for c in cols] for r in rows]
        except (ValueError, IndexError):
            return None
        return _first_nonfinite(np.reshape(xyz, (-1, 3)), lambda i: f"vertex {i + 1}")
    if fmt in ("binary_little_endian", "binary_big_endian"):
        order = "<" if fmt == "binary_little_endian" else ">"
        dtype = np.dtype([(n, order + _PLY_TYPES[p[0]]) for n, p in zip(names, props)])
        if len(data) - body < dtype.itemsize * count:
            return None
        verts = np.frombuffer(data, dtype=dtype, count=count, offset=body)
        return _first_nonfinite(np.stack([verts[c].astype(np.float64) for c in "xyz"], 1), lambda i: f"vertex {i + 1}")
    return None


def nonfinite_vertex(path: str | Path) -> str | None:
    """Where the mesh file ``path`` stores a NaN/inf vertex coordinate (``"line 3 ('v nan 1 0')"``), else None.

    Blender's OBJ/PLY/STL importers replace such values silently (the mesh then renders as something else), so
    the file is checked as written; glTF/GLB keep them and are checked after import (:func:`import_file`).
    """
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in (".obj", ".stl", ".ply"):
        return None
    data = path.read_bytes()
    if suffix == ".obj":
        return _nonfinite_obj(data.decode("utf-8", "replace"))
    if suffix == ".stl":
        return _nonfinite_stl(data)
    return _nonfinite_ply(data)


def import_file(path: str | Path, keep_materials: bool = False, root: str | Path | None = None) -> bpy.types.Object:
    """Import OBJ/PLY/STL/glTF/GLB as ONE mesh object with transforms applied, coordinates as in the file.

    (glTF: the importer's Y-up -> Z-up conversion is undone so that all formats behave alike.)
    ``keep_materials``: keep the file's own materials (OBJ + MTL, glTF PBR; see
    :func:`frng.blender.materials.adopt`), else the object comes without materials.
    Before Blender opens it, every file the mesh names (``mtllib``, an MTL's ``map_Kd`` ..., a glTF buffer or image
    URI) must lie inside ``root`` (default: the mesh's folder; symlinks resolved), else a :class:`MeshError` naming
    the file and the field (:func:`frng.confine.check_mesh_references`); and a glTF's positions must be finite.
    """
    from frng import confine

    path = Path(path)
    if not path.is_file():
        raise MeshError(f"{path}: mesh file does not exist")
    suffix = path.suffix.lower()
    try:
        confine.check_mesh_references(path, root)
    except confine.OutsideError as e:
        raise MeshError(str(e)) from None
    bad = nonfinite_vertex(path)
    if bad is None and suffix in (".gltf", ".glb"):
        bad = confine.gltf_nonfinite_position(path)
    if bad is not None:
        raise MeshError(f"{path}: non-finite vertex coordinate (NaN/inf) at {bad}")
    before = set(bpy.context.scene.objects)
    try:
        with bscene.quiet():
            if suffix == ".obj":
                bpy.ops.wm.obj_import(filepath=str(path), forward_axis="Y", up_axis="Z")
            elif suffix == ".ply":
                bpy.ops.wm.ply_import(filepath=str(path), forward_axis="Y", up_axis="Z")
            elif suffix == ".stl":
                bpy.ops.wm.stl_import(filepath=str(path), forward_axis="Y", up_axis="Z")
            elif suffix in (".gltf", ".glb"):
                bpy.ops.import_scene.gltf(filepath=str(path))
            else:
                raise MeshError(f"{path}: unsupported mesh format {suffix} (use OBJ, PLY, STL, glTF/GLB)")
    except RuntimeError as e:
        raise MeshError(f"{path}: Blender failed to import the mesh ({str(e).strip()})") from e
    new = [o for o in bpy.context.scene.objects if o not in before]
    meshes = [o for o in new if o.type == "MESH" and len(o.data.polygons) > 0]
    if not meshes:
        raise MeshError(f"{path}: the file contains no mesh with faces")
    # bake every object's world transform (incl. parents) into its vertices, then join
    for o in meshes:
        if o.data.users > 1:
            o.data = o.data.copy()
        o.data.transform(o.matrix_world)
    for o in new:
        if o not in meshes:
            bpy.data.objects.remove(o, do_unlink=True)
    for o in meshes:
        o.parent = None
        o.matrix_world = Matrix.Identity(4)
    if len(meshes) > 1:
        _select_only(meshes)
        bpy.ops.object.join()
    obj = bpy.context.view_layer.objects.active if len(meshes) > 1 else meshes[0]
    co = vertices(obj)
    if not np.isfinite(co).all():
        raise MeshError(
            f"{path}: {int((~np.isfinite(co).all(axis=1)).sum())} of {len(co)} vertices have non-finite "
            "coordinates (NaN/inf)"
        )
    if suffix in (".gltf", ".glb"):
        transform_mesh(obj, np.linalg.inv(Y_UP_TO_Z_UP))
    obj.name = "frng_object"
    if not keep_materials:
        obj.data.materials.clear()
    return obj


# -- primitives and procedural shapes --------------------------------------------------------------------


def primitive(kind: str, rng: np.random.Generator) -> tuple[bpy.types.Object, dict]:
    """A Blender primitive with a random anisotropic scale and orientation. Returns (object, parameters)."""
    ops = {
        "cube": lambda: bpy.ops.mesh.primitive_cube_add(calc_uvs=True),
        "uv_sphere": lambda: _uv_sphere(segments=48, rings=24),  # not Blender's: see _uv_sphere
        "ico_sphere": lambda: bpy.ops.mesh.primitive_ico_sphere_add(subdivisions=2, calc_uvs=True),
        "cylinder": lambda: bpy.ops.mesh.primitive_cylinder_add(vertices=48, calc_uvs=True),
        "cone": lambda: bpy.ops.mesh.primitive_cone_add(vertices=48, calc_uvs=True),
        "torus": lambda: bpy.ops.mesh.primitive_torus_add(
            major_segments=64, minor_segments=24, minor_radius=float(rng.uniform(0.15, 0.4))
        ),
        "monkey": lambda: bpy.ops.mesh.primitive_monkey_add(calc_uvs=True),
    }
    if kind not in ops:
        raise MeshError(f"unknown primitive {kind!r}")
    built = ops[kind]()
    obj = built if isinstance(built, bpy.types.Object) else bpy.context.active_object
    scale = rng.uniform(0.6, 1.4, 3)
    euler = (
        rng.uniform(-math.pi, math.pi, 3)
        if kind not in ("monkey",)
        else np.array([0.0, 0.0, rng.uniform(-math.pi, math.pi)])
    )
    m = Matrix.LocRotScale(None, __import__("mathutils").Euler(euler.tolist()), scale.tolist())
    obj.data.transform(m)
    _shade_smooth(obj, kind not in ("cube",))
    if kind == "monkey":
        mod = obj.modifiers.new("subsurf", "SUBSURF")
        mod.levels = mod.render_levels = 1
    return obj, {"kind": kind, "scale": scale.round(4).tolist(), "euler": euler.round(4).tolist()}


def _grid_faces(nu: int, nv: int, wrap_u: bool = True) -> list:
    faces = []
    for j in range(nv - 1):
        for i in range(nu if wrap_u else nu - 1):
            a, b = j * nu + i, j * nu + (i + 1) % nu
            faces.append((a, b, b + nu, a + nu))
    return faces


def _cap(verts: list, faces: list, ring: range, point) -> None:
    c = len(verts)
    verts.append(point)
    idx = list(ring)
    for i in range(len(idx)):
        faces.append((idx[i], idx[(i + 1) % len(idx)], c))


def procedural(kind: str, rng: np.random.Generator) -> tuple[bpy.types.Object, dict]:
    """A procedurally built shape (numpy geometry). Returns (object, parameters)."""
    if kind == "superquadric":
        e1, e2 = rng.uniform(0.3, 2.0, 2)
        axes = rng.uniform(0.5, 1.0, 3)
        nu, nv = 48, 25
        u = np.linspace(-math.pi, math.pi, nu, endpoint=False)
        v = np.linspace(-math.pi / 2, math.pi / 2, nv)[1:-1]
        sp = lambda x, e: np.sign(x) * np.abs(x) ** e  # noqa: E731
        U, V = np.meshgrid(u, v)
        verts = (
            np.stack(
                [
                    axes[0] * sp(np.cos(V), e1) * sp(np.cos(U), e2),
                    axes[1] * sp(np.cos(V), e1) * sp(np.sin(U), e2),
                    axes[2] * sp(np.sin(V), e1),
                ],
                -1,
            )
            .reshape(-1, 3)
            .tolist()
        )
        faces = _grid_faces(nu, nv - 2)
        n = len(verts)
        _cap(verts, faces, range(nu - 1, -1, -1), (0, 0, -axes[2]))
        _cap(verts, faces, range(n - nu, n), (0, 0, axes[2]))
        params = {"e1": e1, "e2": e2, "axes": axes.tolist()}
        smooth = True
    elif kind == "lathe":
        nu, nv = 48, 40
        z = np.linspace(-1, 1, nv)
        k = rng.uniform(1, 4, 3)
        ph = rng.uniform(0, 2 * math.pi, 3)
        amp = rng.uniform(0.05, 0.25, 3)
        r = 0.45 + sum(a * np.sin(kk * z * math.pi / 2 + p) for a, kk, p in zip(amp, k, ph))
        r = np.clip(r, 0.08, 1.0)
        u = np.linspace(0, 2 * math.pi, nu, endpoint=False)
        verts = np.stack([r[:, None] * np.cos(u), r[:, None] * np.sin(u), np.broadcast_to(z[:, None], (nv, nu))], -1)
        verts = verts.reshape(-1, 3).tolist()
        faces = _grid_faces(nu, nv)
        n = len(verts)
        _cap(verts, faces, range(nu - 1, -1, -1), (0, 0, -1))
        _cap(verts, faces, range(n - nu, n), (0, 0, 1))
        params = {"freq": k.tolist(), "phase": ph.tolist(), "amp": amp.tolist()}
        smooth = True
    elif kind in ("blob", "cluster"):
        bpy.ops.mesh.primitive_ico_sphere_add(subdivisions=4)
        base = bpy.context.active_object
        p = vertices(base)
        bpy.data.objects.remove(base, do_unlink=True)
        faces = None
        if kind == "blob":
            d = np.ones(len(p))
            freqs = rng.normal(0, 2.0, (6, 3))
            phases = rng.uniform(0, 2 * math.pi, 6)
            amps = rng.uniform(0.05, 0.2, 6)
            for f, ph_, a in zip(freqs, phases, amps):
                d += a * np.sin(p @ f + ph_)
            verts_all = [p * d[:, None]]
            params = {"freqs": freqs.round(4).tolist(), "amps": amps.round(4).tolist()}
        else:
            n_parts = int(rng.integers(3, 6))
            centres = rng.uniform(-0.6, 0.6, (n_parts, 3))
            radii = rng.uniform(0.25, 0.55, (n_parts, 3))
            verts_all = [c + p * r for c, r in zip(centres, radii)]
            params = {"centres": centres.round(4).tolist(), "radii": radii.round(4).tolist()}
        # rebuild faces of the ico sphere for each part
        bpy.ops.mesh.primitive_ico_sphere_add(subdivisions=4)
        tmp = bpy.context.active_object
        tri = [tuple(poly.vertices) for poly in tmp.data.polygons]
        bpy.data.objects.remove(tmp, do_unlink=True)
        verts, faces = [], []
        for part in verts_all:
            off = len(verts)
            verts.extend(part.tolist())
            faces.extend(tuple(i + off for i in t) for t in tri)
        smooth = True
    elif kind == "twisted_box":
        n = 24
        twist = rng.uniform(-math.pi, math.pi)
        taper = rng.uniform(0.3, 1.0)
        hx, hy = rng.uniform(0.3, 0.7, 2)
        z = np.linspace(-1, 1, n)
        corners = np.array([[-hx, -hy], [hx, -hy], [hx, hy], [-hx, hy]])
        rings = []
        for zz in z:
            a = twist * (zz + 1) / 2
            s = 1.0 + (taper - 1.0) * (zz + 1) / 2
            R = np.array([[math.cos(a), -math.sin(a)], [math.sin(a), math.cos(a)]])
            xy = (corners * s) @ R.T
            rings.append(np.c_[xy, np.full(4, zz)])
        verts = np.concatenate(rings).tolist()
        faces = _grid_faces(4, n)
        faces.append((3, 2, 1, 0))
        m = len(verts)
        faces.append((m - 4, m - 3, m - 2, m - 1))
        params = {"twist": twist, "taper": taper, "half_extent": [hx, hy]}
        smooth = False
    else:
        raise MeshError(f"unknown procedural shape {kind!r}")
    obj = _mesh_object(f"frng_{kind}", np.asarray(verts), faces)
    _shade_smooth(obj, smooth)
    if kind in ("twisted_box", "lathe", "superquadric", "cluster"):
        euler = rng.uniform(-math.pi, math.pi, 3)
        obj.data.transform(Matrix.LocRotScale(None, __import__("mathutils").Euler(euler.tolist()), None))
        params["euler"] = euler.round(4).tolist()
    params = {
        "kind": kind,
        **{k: (round(float(v), 4) if isinstance(v, (float, np.floating)) else v) for k, v in params.items()},
    }
    return obj, params


# -- the object of a dataset entry ------------------------------------------------------------------------


FILE_SOURCES = ("pybullet", "user", "objaverse", "libero")  # sources whose objects come from files on disk


def mesh_path(spec, pybullet_dir, path: Path | None = None) -> Path:
    """The file (a LIBERO object: its folder) a file-backed ``spec`` (:data:`FILE_SOURCES`) is read from: ``path``
    when given (an Objaverse uid resolved in the local cache), a pybullet mesh inside ``pybullet_dir``, else
    ``spec.mesh`` itself."""
    if path is not None:
        return Path(path)
    return Path(pybullet_dir) / spec.mesh if spec.source == "pybullet" else Path(spec.mesh)


def load(
    spec,
    rng: np.random.Generator,
    pybullet_dir: Path | None,
    radius: float = 1.0,
    keep_materials: bool = False,
    path: Path | None = None,
) -> tuple[bpy.types.Object, dict]:
    """Build the object of a :class:`frng.plan.catalog.ObjectSpec`, Z-up, normalised into ``radius``.

    ``keep_materials``: file meshes keep their own materials (``material: own``). ``path``: the mesh file when
    the spec names it indirectly (an Objaverse uid resolved in the local cache).

    Returns (object, info); info has ``file_to_world`` (4x4 list, file points -> world) for file meshes,
    ``params`` for generated shapes, ``had_uvs``, ``vertices`` and ``faces`` counts.
    """
    info: dict = {}
    if spec.source in FILE_SOURCES:
        path = mesh_path(spec, pybullet_dir, path)
        try:
            if spec.source == "libero":  # an object folder: its visual OBJs, joined
                from frng.plan.object_files import libero_meshes

                parts = [import_file(f, keep_materials, root=path) for f in libero_meshes(path)]
                if len(parts) > 1:
                    _select_only(parts)
                    bpy.ops.object.join()
                obj = bpy.context.view_layer.objects.active if len(parts) > 1 else parts[0]
            else:
                # the package's own meshes share textures across its folders (torus/*.mtl: ../cube.png)
                obj = import_file(path, keep_materials, root=pybullet_dir if spec.source == "pybullet" else None)
        except MeshError as e:
            raise MeshError(f"object {spec.id}: {e}") from e
        pre = np.diag(list(spec.prescale) + [1.0])
        up = Y_UP_TO_Z_UP if spec.up == "y" else np.eye(4)
        m = up @ pre
        transform_mesh(obj, m)
    elif spec.source == "primitives":
        obj, info["params"] = primitive(spec.mesh, rng)
        m = np.eye(4)
    elif spec.source == "procedural":
        obj, info["params"] = procedural(spec.mesh, rng)
        m = np.eye(4)
    else:
        raise MeshError(f"object {spec.id}: unknown source {spec.source!r}")
    co = vertices(obj)
    if not np.isfinite(co).all():
        raise MeshError(f"object {spec.id} ({spec.mesh}): vertices with non-finite coordinates (NaN/inf)")
    try:
        norm = normalisation(co, radius)
    except MeshError as e:
        raise MeshError(f"object {spec.id} ({spec.mesh}): {e}") from e
    transform_mesh(obj, norm)
    info["file_to_world"] = (norm @ m).tolist()
    info["radius"] = radius
    info["had_uvs"] = ensure_uvs(obj)
    info["vertices"] = len(obj.data.vertices)
    info["faces"] = len(obj.data.polygons)
    obj.name = "frng_object"
    return obj, info
