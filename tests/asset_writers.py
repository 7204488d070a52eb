"""Tiny textured assets written by the tests themselves (no downloads): a box as OBJ + MTL, as glTF binary (GLB,
metallic-roughness PBR with textures, factors, vertex colours, extensions) and as PLY with vertex colours.

Every box face carries the whole [0, 1]^2 UV square, so a texture whose left half (u < 0.5) differs from its right
half shows both halves on every face. Box half extents (1, 0.6, 0.4), file coordinates Z-up for OBJ (written so)
and Y-up for glTF (as the format says).
"""

from __future__ import annotations

import json
import struct
from pathlib import Path

import numpy as np
from PIL import Image

HALF = (1.0, 0.6, 0.4)


def box_faces(half=HALF):
    """[(corners (4, 3) counter-clockwise seen from outside, normal (3,), u axis (3,))] for the 6 faces."""
    h = np.asarray(half, float)
    faces = []
    for axis in range(3):
        for sign in (1.0, -1.0):
            n = np.zeros(3)
            n[axis] = sign
            u = np.zeros(3)
            u[(axis + 1) % 3] = 1.0
            v = np.cross(n, u)
            c = n * h
            hu, hv = float(np.abs(u) @ h), float(np.abs(v) @ h)
            pts = np.array([c - u * hu - v * hv, c + u * hu - v * hv, c + u * hu + v * hv, c - u * hu + v * hv])
            faces.append((pts, n, u))
    return faces


UV = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]])  # per face corner (OBJ/glTF differ in v: see writers)


def halves(left, right, size: int = 16) -> np.ndarray:
    """(size, size, C) uint8 image: columns u < 0.5 hold ``left``, the others ``right``."""
    left, right = np.asarray(left, np.uint8), np.asarray(right, np.uint8)
    img = np.zeros((size, size, len(left)), np.uint8)
    img[:, : size // 2] = left
    img[:, size // 2 :] = right
    return img


def png_bytes(img: np.ndarray) -> bytes:
    import io

    buf = io.BytesIO()
    Image.fromarray(np.asarray(img, np.uint8)).save(buf, format="PNG")
    return buf.getvalue()


def srgb_to_linear(c):
    c = np.asarray(c, float) / 255.0
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)


# -- OBJ + MTL ---------------------------------------------------------------------------------------------------


def write_obj(
    folder: Path, stem: str, mtl: str | None, textures: dict[str, np.ndarray] | None = None, material: str = "mat"
) -> Path:
    """``{stem}.obj`` (+ ``{stem}.mtl`` holding the text ``mtl`` when given, + PNG ``textures`` by file name)."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    lines = [f"mtllib {stem}.mtl"] if mtl is not None else []
    vi = 1
    for pts, _, _ in box_faces():
        lines += [f"v {x:.6f} {y:.6f} {z:.6f}" for x, y, z in pts]
    lines += [f"vt {u} {v}" for u, v in UV]
    if mtl is not None:
        lines.append(f"usemtl {material}")
    for _ in range(6):
        lines.append("f " + " ".join(f"{vi + k}/{k + 1}" for k in range(4)))
        vi += 4
    path = folder / f"{stem}.obj"
    path.write_text("\n".join(lines) + "\n")
    if mtl is not None:
        (folder / f"{stem}.mtl").write_text(mtl)
    for name, img in (textures or {}).items():
        (folder / name).write_bytes(png_bytes(img))
    return path


# -- glTF binary ---------------------------------------------------------------------------------------------------


def write_glb(
    path: Path,
    material: dict | None,
    images: dict[str, np.ndarray] | None = None,
    colors: np.ndarray | None = None,
    extensions_used: list[str] | None = None,
) -> Path:
    """A box (Y-up file coordinates: the box's file Z axis is written as glTF's -Y... no: written as given, the
    reader treats Y as up) as a GLB. ``material``: the glTF material object, textures referenced as
    ``{"index": name}`` with ``name`` a key of ``images`` (PNG-encoded into the binary chunk). ``colors``:
    optional per-vertex RGBA floats (24, 4) as COLOR_0."""
    images = images or {}
    pos, nrm, uv, idx = [], [], [], []
    for f, (pts, n, _) in enumerate(box_faces()):
        pos.append(pts)
        nrm.append(np.repeat(n[None], 4, 0))
        uv.append(np.stack([UV[:, 0], 1.0 - UV[:, 1]], 1))  # glTF: v down
        idx += [4 * f + k for k in (0, 1, 2, 0, 2, 3)]
    attrs = {
        "POSITION": np.concatenate(pos).astype(np.float32),
        "NORMAL": np.concatenate(nrm).astype(np.float32),
        "TEXCOORD_0": np.concatenate(uv).astype(np.float32),
    }
    if colors is not None:
        attrs["COLOR_0"] = np.asarray(colors, np.float32)
    blob = bytearray()
    views, accessors = [], []

    def add_view(data: bytes) -> int:
        while len(blob) % 4:
            blob.append(0)
        views.append({"buffer": 0, "byteOffset": len(blob), "byteLength": len(data)})
        blob.extend(data)
        return len(views) - 1

    prim_attrs = {}
    for name, arr in attrs.items():
        v = add_view(arr.tobytes())
        acc = {"bufferView": v, "componentType": 5126, "count": len(arr), "type": f"VEC{arr.shape[1]}"}
        if name == "POSITION":
            acc["min"], acc["max"] = arr.min(0).tolist(), arr.max(0).tolist()
        accessors.append(acc)
        prim_attrs[name] = len(accessors) - 1
    v = add_view(np.asarray(idx, np.uint16).tobytes())
    accessors.append({"bufferView": v, "componentType": 5123, "count": len(idx), "type": "SCALAR"})
    prim = {"attributes": prim_attrs, "indices": len(accessors) - 1}
    gltf = {
        "asset": {"version": "2.0", "generator": "frng tests"},
        "scene": 0,
        "scenes": [{"nodes": [0]}],
        "nodes": [{"mesh": 0, "name": "box"}],
        "meshes": [{"primitives": [prim]}],
    }
    names = list(images)
    if names:
        gltf["images"] = [
            {"bufferView": add_view(png_bytes(images[n])), "mimeType": "image/png", "name": n} for n in names
        ]
        gltf["samplers"] = [{"magFilter": 9728, "minFilter": 9728}]  # nearest: texel values stay exact
        gltf["textures"] = [{"source": i, "sampler": 0} for i in range(len(names))]
    if material is not None:
        mat = json.loads(json.dumps(material))

        def fix(node):
            if isinstance(node, dict):
                for k, val in node.items():
                    if k == "index" and isinstance(val, str):
                        node[k] = names.index(val)
                    else:
                        fix(val)
            elif isinstance(node, list):
                for val in node:
                    fix(val)

        fix(mat)
        gltf["materials"] = [mat]
        prim["material"] = 0
    if extensions_used:
        gltf["extensionsUsed"] = list(extensions_used)
    while len(blob) % 4:
        blob.append(0)
    gltf["buffers"] = [{"byteLength": len(blob)}]
    gltf["bufferViews"] = views
    gltf["accessors"] = accessors
    js = json.dumps(gltf).encode()
    js += b" " * (-len(js) % 4)
    out = struct.pack("<III", 0x46546C67, 2, 12 + 8 + len(js) + 8 + len(blob))
    out += struct.pack("<II", len(js), 0x4E4F534A) + js + struct.pack("<II", len(blob), 0x004E4942) + bytes(blob)
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    Path(path).write_bytes(out)
    return Path(path)


# -- PLY ---------------------------------------------------------------------------------------------------------


def write_ply(path: Path, rgb=(200, 40, 40)) -> Path:
    """The box as ASCII PLY with uchar vertex colours ``rgb`` (sRGB bytes)."""
    verts, faces = [], []
    for f, (pts, _, _) in enumerate(box_faces()):
        verts += [f"{x:.6f} {y:.6f} {z:.6f} {rgb[0]} {rgb[1]} {rgb[2]}" for x, y, z in pts]
        faces.append("4 " + " ".join(str(4 * f + k) for k in range(4)))
    head = [
        "ply",
        "format ascii 1.0",
        f"element vertex {len(verts)}",
        "property float x",
        "property float y",
        "property float z",
        "property uchar red",
        "property uchar green",
        "property uchar blue",
        f"element face {len(faces)}",
        "property list uchar int vertex_indices",
        "end_header",
    ]
    Path(path).write_text("\n".join(head + verts + faces) + "\n")
    return Path(path)
