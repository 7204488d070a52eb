"""The relightable glTF: a GLB whose Gaussians are a KHR_gaussian_splatting primitive baked under one light (what
any KHR viewer shows) and whose vendor extension ``FRNG_relightable_gaussians`` carries the per-Gaussian neural
features and the decoder (weights and architecture), so ``frng render-asset`` / ``frng view`` relight the file
itself. Specification: docs/asset-gltf-extension.md, JSON schema docs/schema/FRNG_relightable_gaussians.schema.json.

Written with pygltflib (:func:`write_glb`), read back into an asset's parts (:func:`load_glb`, the same tuple as
:func:`frng.apps.asset.load_asset`). The Gaussians are stored once, as the KHR attributes in glTF axes (Y up):
reading converts them back to the asset's axes (Z up): ``(x, y, z)_asset = (x, -z, y)_gltf``, quaternions by the
inverse frame rotation; features and decoder weights come back bit-exact, the rest to float32 rounding.
"""

from __future__ import annotations

import io as _io
import os
from pathlib import Path

import numpy as np
import torch

EXTENSION = "FRNG_relightable_gaussians"
KHR = "KHR_gaussian_splatting"
EXTENSION_VERSION = 1  # = frng.apps.asset.FORMAT_VERSION of the asset it carries
COLOR_SPACE = "srgb_rec709_display"
FLOAT, UBYTE = 5126, 5121
ARRAY_BUFFER = 34962
# asset.json keys the extension keeps (the rest describe the PLY file, which a GLB does not have)
ASSET_KEYS = ("object_id", "source_views", "decoder", "render", "rig", "created", "conventions")


def _pad4(b: bytes) -> bytes:
    return b + b"\0" * (-len(b) % 4)


def decoder_state(renderer) -> dict[str, torch.Tensor]:
    """An :class:`~frng.apps.asset.AssetRenderer`'s decoder weights as ``decoder.safetensors`` holds them (the
    coverage head's under ``coverage.``)."""
    from frng.model.coverage import COVERAGE_PREFIX

    state = {k: v.detach().cpu().contiguous() for k, v in renderer.decoder.state_dict().items()}
    if renderer.coverage is not None:
        state.update(
            {COVERAGE_PREFIX + k: v.detach().cpu().contiguous() for k, v in renderer.coverage.state_dict().items()}
        )
    return state


def write_glb(path: str | os.PathLike, baked, renderer) -> None:
    """A bake (:class:`frng.apps.export.Baked`) of ``renderer``'s asset as a relightable GLB, atomically."""
    import pygltflib as gl
    from safetensors.torch import save

    from frng.apps.asset import FORMAT_VERSION
    from frng.apps.splat_axes import Y_UP, Y_UP_QUAT
    from frng.io import atomic_path, srgb_decode

    means, quats = baked.in_frame(Y_UP, Y_UP_QUAT)
    sh = baked.sh(Y_UP)  # (N, 16, 3)
    n = len(baked)
    feats = renderer.gaussians.features.detach().cpu().float().numpy()
    assert feats.shape[0] == n, (feats.shape, n)
    dc = np.clip(sh[:, 0, :] * 0.28209479177387814 + 0.5, 0.0, 1.0)
    colour = np.concatenate([srgb_decode(dc.astype(np.float32)), baked.opacities[:, None]], 1)

    blob, views, accessors = b"", [], []

    def view(data: bytes, target: int | None = None) -> int:
        nonlocal blob
        views.append(gl.BufferView(buffer=0, byteOffset=len(blob), byteLength=len(data), target=target))
        blob = _pad4(blob + data)
        return len(views) - 1

    def accessor(a: np.ndarray, kind: str, bounds: bool = False) -> int:
        a = np.ascontiguousarray(a, dtype="<f4")
        acc = gl.Accessor(bufferView=view(a.tobytes(), ARRAY_BUFFER), componentType=FLOAT, count=n, type=kind)
        if bounds:
            acc.min, acc.max = a.min(0).tolist(), a.max(0).tolist()
        accessors.append(acc)
        return len(accessors) - 1

    attrs = gl.Attributes(POSITION=accessor(means, "VEC3", True), COLOR_0=accessor(colour, "VEC4"))
    xyzw = np.concatenate([quats[:, 1:], quats[:, :1]], 1)
    xyzw /= np.linalg.norm(xyzw, axis=1, keepdims=True)
    setattr(attrs, f"{KHR}:ROTATION", accessor(xyzw, "VEC4"))
    setattr(attrs, f"{KHR}:SCALE", accessor(baked.scales, "VEC3"))
    setattr(attrs, f"{KHR}:OPACITY", accessor(np.clip(baked.opacities, 0.0, 1.0), "SCALAR"))
    for degree in range(4):
        for m in range(2 * degree + 1):
            setattr(attrs, f"{KHR}:SH_DEGREE_{degree}_COEF_{m}", accessor(sh[:, degree * degree + m, :], "VEC3"))
    meta = renderer.meta
    ext = {
        "version": FORMAT_VERSION,
        "featureDim": int(feats.shape[1]),
        "features": view(np.ascontiguousarray(feats, "<f4").tobytes()),
        "decoder": {
            "weights": view(save(decoder_state(renderer))),
            "architecture": dict(meta["decoder"]),
        },
        "asset": {k: meta[k] for k in ASSET_KEYS if meta.get(k) is not None},
        "bakedLight": {k: v for k, v in baked.light.items()},
    }
    prim = gl.Primitive(
        attributes=attrs,
        mode=gl.POINTS,
        extensions={
            KHR: {
                "kernel": "ellipse",
                "colorSpace": COLOR_SPACE,
                "projection": "perspective",
                "sortingMethod": "cameraDistance",
                "extensions": {EXTENSION: ext},
            }
        },
    )
    doc = gl.GLTF2(
        asset=gl.Asset(version="2.0", generator="frng export-asset"),
        scene=0,
        scenes=[gl.Scene(nodes=[0])],
        nodes=[gl.Node(mesh=0, name=str(meta.get("object_id", "asset")))],
        meshes=[gl.Mesh(primitives=[prim], name=str(meta.get("object_id", "asset")))],
        accessors=accessors,
        bufferViews=views,
        buffers=[gl.Buffer(byteLength=len(blob))],
        extensionsUsed=[KHR, EXTENSION],
    )
    doc.set_binary_blob(blob)
    with atomic_path(path) as tmp:
        doc.save_binary(str(tmp))


def _read_view(doc, blob: bytes, index, path: Path, field: str) -> bytes:
    from frng.apps.asset import AssetError

    if isinstance(index, bool) or not isinstance(index, int) or not 0 <= index < len(doc.bufferViews or []):
        raise AssetError(f"{path}: field '{field}' is {index!r}, not a bufferView index")
    v = doc.bufferViews[index]
    start = int(v.byteOffset or 0)
    if v.buffer != 0 or start + v.byteLength > len(blob):
        raise AssetError(f"{path}: field '{field}': bufferView {index} lies outside the GLB's binary chunk")
    return blob[start : start + v.byteLength]


def _read_accessor(doc, blob: bytes, attrs: dict, name: str, width: int, path: Path) -> np.ndarray:
    from frng.apps.asset import AssetError

    if name not in attrs:
        raise AssetError(f"{path}: the {KHR} primitive has no attribute {name!r}")
    i = attrs[name]
    acc = doc.accessors[i] if isinstance(i, int) and 0 <= i < len(doc.accessors or []) else None
    kinds = {1: "SCALAR", 3: "VEC3", 4: "VEC4"}
    if acc is None or acc.componentType != FLOAT or acc.type != kinds[width] or acc.bufferView is None:
        raise AssetError(f"{path}: attribute {name!r} must be a float {kinds[width]} accessor")
    raw = _read_view(doc, blob, acc.bufferView, path, f"accessors[{i}].bufferView")
    stride = doc.bufferViews[acc.bufferView].byteStride or 4 * width
    off = int(acc.byteOffset or 0)
    if stride != 4 * width or off + acc.count * stride > len(raw):
        raise AssetError(f"{path}: attribute {name!r}: accessor {i} does not fit its bufferView (or is interleaved)")
    return np.frombuffer(raw, "<f4", acc.count * width, off).reshape(acc.count, width).astype(np.float64)


def load_glb(path: str | os.PathLike) -> tuple:
    """A relightable GLB -> (gaussians, features (N, C), decoder state_dict, meta) as
    :func:`frng.apps.asset.load_asset` returns for a folder (asset axes). Raises
    :class:`~frng.apps.asset.AssetError` naming the file and field."""
    import pygltflib as gl
    from safetensors import SafetensorError
    from safetensors.torch import load

    from frng.apps.asset import FORMAT, FORMAT_VERSION, AssetError, ply_fields_to_gaussians
    from frng.apps.splat_axes import Y_UP, Y_UP_QUAT, quat_multiply

    path = Path(path)
    try:
        doc = gl.GLTF2().load_binary_from_file_object(_io.BytesIO(path.read_bytes()))
    except OSError as e:
        raise AssetError(f"{path}: cannot read ({e.strerror or e})") from None
    except Exception as e:  # pygltflib raises whatever its JSON / struct parsing raises
        raise AssetError(
            f"{path}: not a glTF binary ({str(e).splitlines()[0][:200] if str(e) else type(e).__name__})"
        ) from None
    blob = doc.binary_blob() or b""
    found = None
    for mesh in doc.meshes or []:
        for prim in mesh.primitives:
            khr = (prim.extensions or {}).get(KHR) or {}
            if EXTENSION in (khr.get("extensions") or {}):
                found = (prim, khr["extensions"][EXTENSION])
                break
    if found is None:
        raise AssetError(
            f"{path}: no {KHR} primitive with the {EXTENSION} extension (a plain splat file is baked under one light "
            f"and cannot be relit; export it with `frng export-asset --format glb`)"
        )
    prim, ext = found
    if ext.get("version") != FORMAT_VERSION:
        raise AssetError(
            f"{path}: field '{EXTENSION}.version' is {ext.get('version')!r}; this frng reads version {FORMAT_VERSION}"
        )
    attrs = {k: v for k, v in prim.attributes.__dict__.items() if v is not None}
    pos = _read_accessor(doc, blob, attrs, "POSITION", 3, path)
    n = pos.shape[0]
    rot = _read_accessor(doc, blob, attrs, f"{KHR}:ROTATION", 4, path)
    scale = _read_accessor(doc, blob, attrs, f"{KHR}:SCALE", 3, path)
    opac = _read_accessor(doc, blob, attrs, f"{KHR}:OPACITY", 1, path)[:, 0]
    c = ext.get("featureDim")
    if isinstance(c, bool) or not isinstance(c, int) or not 0 <= c <= 4096:
        raise AssetError(f"{path}: field '{EXTENSION}.featureDim' must be an integer in 0..4096, got {c!r}")
    raw = _read_view(doc, blob, ext.get("features"), path, f"{EXTENSION}.features")
    if len(raw) != 4 * n * c:
        raise AssetError(f"{path}: field '{EXTENSION}.features': {len(raw)} bytes, expected {n} x {c} float32")
    feats = np.frombuffer(raw, "<f4").reshape(n, c)
    dec = ext.get("decoder") or {}
    if not isinstance(dec.get("architecture"), dict):
        raise AssetError(f"{path}: field '{EXTENSION}.decoder.architecture' must be an object")
    try:
        state = load(_read_view(doc, blob, dec.get("weights"), path, f"{EXTENSION}.decoder.weights"))
    except (SafetensorError, ValueError) as e:
        raise AssetError(f"{path}: field '{EXTENSION}.decoder.weights': not safetensors ({e})") from None
    for k, v in state.items():
        if not v.is_floating_point() or not torch.isfinite(v).all():
            raise AssetError(f"{path}: field '{EXTENSION}.decoder.weights': tensor {k!r} is not finite floating point")
    if (scale <= 0).any() or not ((opac > 0) & (opac <= 1)).all():
        raise AssetError(f"{path}: attribute {KHR}:SCALE must be > 0 and {KHR}:OPACITY in (0, 1]")
    means = pos @ Y_UP  # glTF -> asset axes (Y_UP is a rotation: its inverse is its transpose)
    inv = Y_UP_QUAT * np.array([1.0, -1.0, -1.0, -1.0])
    quats = quat_multiply(inv[None], np.concatenate([rot[:, 3:], rot[:, :3]], 1))
    op = np.clip(opac, 1e-7, 1 - 1e-7)
    fields = {"x": means[:, 0], "y": means[:, 1], "z": means[:, 2]}
    fields.update({k: np.zeros(n) for k in ("nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2")})
    fields["opacity"] = np.log(op) - np.log1p(-op)
    fields.update({f"scale_{i}": np.log(scale[:, i]) for i in range(3)})
    fields.update({f"rot_{i}": quats[:, i] for i in range(4)})
    fields.update({f"feat_{i}": feats[:, i] for i in range(c)})
    gaussians, features, preview = ply_fields_to_gaussians(fields, source=str(path))
    gaussians.features = features = torch.from_numpy(feats.copy())
    meta = {
        **{k: v for k, v in (ext.get("asset") or {}).items() if k in ASSET_KEYS},
        "format": FORMAT,
        "version": FORMAT_VERSION,
        "num_gaussians": n,
        "feature_dim": c,
        "decoder": dict(dec["architecture"]),
        "preview_rgb": preview,
    }
    meta.setdefault("object_id", path.stem)
    return gaussians, features, state, meta


def open_renderer(path: str | os.PathLike, device: str | torch.device = "cpu", bf16: bool = False):
    """An :class:`~frng.apps.asset.AssetRenderer` of an asset folder or of a relightable GLB (``*.glb``, a file):
    what ``frng render-asset``, ``frng view`` and ``frng export-asset`` open."""
    from frng.apps.asset import AssetRenderer

    path = Path(path)
    if path.suffix.lower() == ".glb" and path.is_file():
        return AssetRenderer(path, device, bf16, parts=load_glb(path))
    return AssetRenderer(path, device, bf16)


__all__ = ["COLOR_SPACE", "EXTENSION", "KHR", "decoder_state", "load_glb", "open_renderer", "write_glb"]
