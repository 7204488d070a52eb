"""The relightable asset: an object reconstructed once by F-RNG, saved so it can be relit without the model.

An asset is a folder with three files::

    {asset}/gaussians.ply         3DGS-style binary little-endian PLY, one vertex per Gaussian
    {asset}/decoder.safetensors   the universal neural appearance decoder's weights (a torch state_dict); with
                                  decoder.coverage_hidden > 0 also the silhouette rim's coverage head's, under
                                  ``coverage.`` (frng/model/coverage.py; applied to every rasterized view)
    {asset}/asset.json            format version, feature dim, decoder architecture, object id, provenance

``gaussians.ply`` properties (all ``float``, i.e. float32, in this order)::

    x y z                  centre (world units; world Z up, object in the unit sphere)
    nx ny nz               zeros (3DGS writes them; viewers ignore them)
    f_dc_0 f_dc_1 f_dc_2   SH degree-0 coefficients of a display preview colour:
                           f_dc = (srgb_encode(preview_linear) - 0.5) / SH_C0, so 3DGS viewers (which show
                           0.5 + SH_C0 * f_dc as display RGB) show it; grey when no preview is given
    opacity                logit(opacity)                   (3DGS stores pre-sigmoid opacity)
    scale_0 scale_1 scale_2  log(scale)                     (3DGS stores log standard deviations)
    rot_0 rot_1 rot_2 rot_3  unit quaternion (w, x, y, z)   (3DGS's and gsplat's order)
    feat_0 ... feat_{C-1}  the per-Gaussian neural material features F-RNG's decoder reads

Standard 3DGS viewers load it as a degree-0 splat (no ``f_rest_*``) and ignore the ``feat_*`` properties.
Round trip: positions, rotations and features come back bit-exact; opacities and scales go through float64
logit/log and come back to float32 precision (relative error ~1e-7, what a float32 logit/log can hold).

``asset.json`` (version :data:`FORMAT_VERSION`)::

    {"format": "frng-asset", "version": 1, "num_gaussians": N, "feature_dim": C,
     "ply": "gaussians.ply", "decoder_weights": "decoder.safetensors",
     "ply_properties": [...],                       # the property names in order
     "decoder": {"width": 256, "depth": 4, "input_encoding": "...", ...},   # architecture, caller-given
     "object_id": "...", "source_views": [...],     # what it was reconstructed from
     "created": {"utc": "...", "frng_version": "..."},
     "conventions": {...},                          # units, axes, colour space, activations
     "render": {"raster": {...}, "shading": {...}}, # render settings (render_settings(); optional)
     "rig": {"camera_distance", "fov_deg", "resolution"},  # the training rig (frng reconstruct; optional)
     ...any extra keys from the caller's meta}

:class:`AssetRenderer` renders an asset from its folder alone (the decoder rebuilt from ``decoder``, the
rasterizer and shading from ``render``; schema defaults when absent): ``frng render-asset``.

Writes are atomic: everything goes to a hidden temporary folder beside the target, which is renamed into
place only once all three files are complete. Reading validates and raises :class:`AssetError` naming the
file and field at fault.
"""

from __future__ import annotations

import datetime
import os
import shutil
import tempfile
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path

import numpy as np
import torch

from frng.gaussians import Gaussians
from frng.io import atomic_path, read_json, save_safetensors, srgb_decode, srgb_encode, temp_dir, write_json

FORMAT = "frng-asset"
FORMAT_VERSION = 1
PLY_FILE = "gaussians.ply"
DECODER_FILE = "decoder.safetensors"
META_FILE = "asset.json"
SH_C0 = 0.28209479177387814  # degree-0 real spherical harmonic, 1 / (2 sqrt(pi))

BASE_PROPERTIES = (
    "x",
    "y",
    "z",
    "nx",
    "ny",
    "nz",
    "f_dc_0",
    "f_dc_1",
    "f_dc_2",
    "opacity",
    "scale_0",
    "scale_1",
    "scale_2",
    "rot_0",
    "rot_1",
    "rot_2",
    "rot_3",
)
REQUIRED_DECODER_KEYS = ("width", "depth", "input_encoding")
# a PLY's log scales outside are refused (exp(5) = 148 object radii; exp(-80) is still > 0 in float32)
LOG_SCALE_RANGE = (-80.0, 5.0)
MAX_COORDINATE = 1e3  # a PLY's |x|, |y|, |z| above are refused (the object lies in the unit sphere)
MAX_SPP_INFER = 4096  # asset.json render.shading.spp_infer bound (config/schema.yaml shading.spp_infer)
MAX_DECODER_SIZE = 4096  # asset.json decoder.width / feature_dim above are refused (bounded memory before building)
CONVENTIONS = {
    "world": "right-handed, Z up, object normalised into the unit sphere at the origin",
    "units": "world units (object radius 1)",
    "colour": "linear scene-referred RGB (the decoder's output); f_dc_* is an sRGB display preview only",
    "cameras": "OpenCV (x right, y down, z forward), 4x4 camera-to-world + fx, fy, cx, cy in pixels",
    "quaternion": "rot_0..3 = (w, x, y, z), unit norm",
    "opacity": "PLY stores logit(opacity); opacity = sigmoid(value)",
    "scale": "PLY stores log(scale); scale = exp(value) (standard deviations along the rotated axes)",
}


class AssetError(ValueError):
    """An asset or PLY file is missing, malformed or inconsistent. The message names the file (and field)."""


# -- PLY ------------------------------------------------------------------------------------------

_PLY_TYPES = {  # PLY type name -> numpy dtype (without byte order)
    "char": "i1",
    "uchar": "u1",
    "short": "i2",
    "ushort": "u2",
    "int": "i4",
    "uint": "u4",
    "float": "f4",
    "double": "f8",
    "int8": "i1",
    "uint8": "u1",
    "int16": "i2",
    "uint16": "u2",
    "int32": "i4",
    "uint32": "u4",
    "float32": "f4",
    "float64": "f8",
}
_NP_TO_PLY = {
    "i1": "char",
    "u1": "uchar",
    "i2": "short",
    "u2": "ushort",
    "i4": "int",
    "u4": "uint",
    "f4": "float",
    "f8": "double",
}


def write_ply(
    path: str | os.PathLike,
    fields: Mapping[str, np.ndarray],
    element: str = "vertex",
    comments: Sequence[str] = (),
) -> None:
    """Write one PLY element with scalar properties as binary little-endian, atomically.

    fields: name -> (N,) array, in property order; all the same N. Supported dtypes: int8/16/32, uint8/16/32,
    float32, float64 (each keeps its type; convert to float32 first for 3DGS viewers).
    comments: header comment lines (no newlines).
    """
    if not fields:
        raise ValueError(f"{path}: write_ply needs at least one field")
    arrays = {}
    n = None
    for name, arr in fields.items():
        arr = np.asarray(arr)
        if arr.ndim != 1:
            raise ValueError(f"{path}: field {name!r} must be 1-D (N,), got shape {arr.shape}")
        if n is None:
            n = arr.shape[0]
        if arr.shape[0] != n:
            raise ValueError(f"{path}: field {name!r} has {arr.shape[0]} rows, expected {n}")
        code = arr.dtype.str[1:]
        if code not in _NP_TO_PLY:
            raise ValueError(f"{path}: field {name!r} has unsupported dtype {arr.dtype}")
        if not name or any(c.isspace() for c in name):
            raise ValueError(f"{path}: invalid property name {name!r}")
        arrays[name] = arr
    for c in comments:
        if "\n" in c or "\r" in c:
            raise ValueError(f"{path}: PLY comments cannot contain newlines: {c!r}")

    dtype = np.dtype([(name, "<" + arr.dtype.str[1:]) for name, arr in arrays.items()])
    table = np.empty(n, dtype=dtype)
    for name, arr in arrays.items():
        table[name] = arr
    header = ["ply", "format binary_little_endian 1.0"]
    header += [f"comment {c}" for c in comments]
    header.append(f"element {element} {n}")
    header += [f"property {_NP_TO_PLY[arr.dtype.str[1:]]} {name}" for name, arr in arrays.items()]
    header.append("end_header")
    with atomic_path(path) as tmp:
        with open(tmp, "wb") as f:
            f.write(("\n".join(header) + "\n").encode("ascii"))
            f.write(table.tobytes())


def read_ply_header(path: str | os.PathLike) -> dict:
    """Parse a PLY header. Returns {"format", "comments", "elements": [(name, count, [(prop, ply_type)])],
    "header_bytes"}. List properties are rejected (Gaussian splat files have none)."""
    path = Path(path)
    if not path.exists():
        raise AssetError(f"{path}: file does not exist")
    with open(path, "rb") as f:
        first = f.readline()
        if first.rstrip(b"\r\n") != b"ply":
            raise AssetError(f"{path}: not a PLY file (first line {first[:20]!r})")
        fmt, comments, elements = None, [], []
        while True:
            raw = f.readline()
            if not raw:
                raise AssetError(f"{path}: PLY header has no end_header line")
            line = raw.decode("ascii", errors="replace").strip()
            words = line.split()
            if not words:
                continue
            if words[0] == "end_header":
                break
            if words[0] == "format":
                if len(words) != 3 or words[1] not in ("binary_little_endian", "binary_big_endian", "ascii"):
                    raise AssetError(f"{path}: unsupported PLY format line {line!r}")
                fmt = words[1]
            elif words[0] in ("comment", "obj_info"):
                comments.append(line.partition(" ")[2])
            elif words[0] == "element":
                if len(words) != 3 or not words[2].isdigit():
                    raise AssetError(f"{path}: malformed PLY element line {line!r}")
                elements.append((words[1], int(words[2]), []))
            elif words[0] == "property":
                if not elements:
                    raise AssetError(f"{path}: PLY property before any element: {line!r}")
                if len(words) >= 2 and words[1] == "list":
                    raise AssetError(f"{path}: PLY list properties are not supported ({line!r})")
                if len(words) != 3 or words[1] not in _PLY_TYPES:
                    raise AssetError(f"{path}: malformed PLY property line {line!r}")
                elements[-1][2].append((words[2], words[1]))
            else:
                raise AssetError(f"{path}: unknown PLY header line {line!r}")
        header_bytes = f.tell()
    if fmt is None:
        raise AssetError(f"{path}: PLY header has no format line")
    return {"format": fmt, "comments": comments, "elements": elements, "header_bytes": header_bytes}


def _is_number(token: bytes) -> bool:
    try:
        float(token)
        return True
    except ValueError:
        return False


def read_ply(path: str | os.PathLike, element: str = "vertex") -> dict[str, np.ndarray]:
    """Read one element of a PLY (binary either endianness, or ascii) -> name -> (N,) array, header order.

    Values keep their stored type (converted to native byte order). Raises :class:`AssetError` naming the
    file if it is missing, truncated or malformed.
    """
    path = Path(path)
    header = read_ply_header(path)
    fmt = header["format"]
    order = "<" if fmt == "binary_little_endian" else ">"
    dtypes = [np.dtype([(p, order + _PLY_TYPES[t]) for p, t in props]) for _, _, props in header["elements"]]
    names = [e[0] for e in header["elements"]]
    if element not in names:
        raise AssetError(f"{path}: PLY has no element {element!r} (has {names})")
    with open(path, "rb") as f:
        f.seek(header["header_bytes"])
        if fmt == "ascii":
            tokens = f.read().split()
            pos = 0
            for (name, count, props), dt in zip(header["elements"], dtypes):
                k = count * len(props)
                if pos + k > len(tokens):
                    raise AssetError(f"{path}: ascii PLY truncated in element {name!r}")
                if name == element:
                    try:
                        vals = np.array(tokens[pos : pos + k], dtype=np.float64).reshape(count, len(props))
                    except ValueError as e:
                        bad = next((t for t in tokens[pos : pos + k] if not _is_number(t)), None)
                        where = ""
                        if bad is not None:
                            i = tokens[pos : pos + k].index(bad)
                            where = f" at {name} {i // len(props)}, property {props[i % len(props)][0]!r}"
                        raise AssetError(
                            f"{path}: ascii PLY: not a number{where}: "
                            f"{(bad or b'?').decode('ascii', 'replace')!r} ({e})"
                        ) from None
                    return {p: vals[:, i].astype(dt[p].newbyteorder("=")) for i, (p, _) in enumerate(props)}
                pos += k
        data = f.read()
    offset = 0
    for (name, count, props), dt in zip(header["elements"], dtypes):
        nbytes = count * dt.itemsize
        if offset + nbytes > len(data):
            raise AssetError(
                f"{path}: PLY truncated: element {name!r} needs {nbytes} bytes at offset "
                f"{offset}, file has {len(data) - offset} left"
            )
        if name == element:
            table = np.frombuffer(data, dtype=dt, count=count, offset=offset)
            return {p: table[p].astype(dt[p].newbyteorder("="), copy=True) for p, _ in props}
        offset += nbytes
    raise AssertionError("unreachable")


# -- Gaussians <-> 3DGS PLY fields ----------------------------------------------------------------


def _np(x, name: str) -> np.ndarray:
    if isinstance(x, torch.Tensor):
        x = x.detach().cpu().numpy()
    return np.asarray(x)


def gaussians_to_ply_fields(
    gaussians: Gaussians,
    features: np.ndarray | torch.Tensor,
    preview_rgb: np.ndarray | torch.Tensor | None = None,
) -> dict[str, np.ndarray]:
    """Gaussians + features (N, C) [+ preview colour (N, 3), linear [0, 1]] -> 3DGS PLY fields (float32).

    Activations are undone in float64: opacity -> logit, scale -> log. Opacities are clipped to
    [1e-7, 1 - 1e-7] first so the logit is finite.
    """
    means = _np(gaussians.means, "means").astype(np.float64)
    n = means.shape[0]
    quats = _np(gaussians.quats, "quats")
    scales = _np(gaussians.scales, "scales").astype(np.float64)
    opac = _np(gaussians.opacities, "opacities").astype(np.float64).reshape(-1)
    feats = _np(features, "features")
    if feats.ndim != 2 or feats.shape[0] != n:
        raise ValueError(f"features must be (N={n}, C), got {feats.shape}")
    if np.any(scales <= 0):
        raise ValueError("scales must be positive (the PLY stores log(scale))")
    opac = np.clip(opac, 1e-7, 1.0 - 1e-7)
    if preview_rgb is None:
        dc = np.zeros((n, 3))
    else:
        rgb = _np(preview_rgb, "preview_rgb").astype(np.float32)
        if rgb.shape != (n, 3):
            raise ValueError(f"preview_rgb must be (N={n}, 3), got {rgb.shape}")
        dc = (srgb_encode(rgb).astype(np.float64) - 0.5) / SH_C0
    f32 = lambda a: np.ascontiguousarray(a, dtype=np.float32)  # noqa: E731
    out = {"x": f32(means[:, 0]), "y": f32(means[:, 1]), "z": f32(means[:, 2])}
    for k in ("nx", "ny", "nz"):
        out[k] = np.zeros(n, np.float32)
    for i in range(3):
        out[f"f_dc_{i}"] = f32(dc[:, i])
    out["opacity"] = f32(np.log(opac) - np.log1p(-opac))
    for i in range(3):
        out[f"scale_{i}"] = f32(np.log(scales[:, i]))
    for i in range(4):
        out[f"rot_{i}"] = f32(quats[:, i])
    for i in range(feats.shape[1]):
        out[f"feat_{i}"] = f32(feats[:, i])
    return out


def ply_fields_to_gaussians(
    fields: Mapping[str, np.ndarray],
    source: str = "PLY",
) -> tuple[Gaussians, torch.Tensor, torch.Tensor]:
    """3DGS PLY fields -> (Gaussians with features set, features (N, C), preview_rgb (N, 3) linear).

    Activations are applied in float64 then cast to float32: opacity = sigmoid, scale = exp. Features are the
    ``feat_0..feat_{C-1}`` properties (C may be 0). Raises :class:`AssetError` naming ``source`` and the field
    for a missing property, a gap in the feat_ numbering or a non-finite value.
    """
    missing = [k for k in BASE_PROPERTIES if k not in fields]
    if missing:
        raise AssetError(f"{source}: missing PLY properties {missing}")
    feat_names = sorted(
        (k for k in fields if k.startswith("feat_")), key=lambda k: int(k[5:]) if k[5:].isdigit() else -1
    )
    expected = [f"feat_{i}" for i in range(len(feat_names))]
    if feat_names != expected:
        raise AssetError(f"{source}: feature properties must be feat_0..feat_{len(feat_names) - 1}, got {feat_names}")
    for k in list(BASE_PROPERTIES) + feat_names:
        bad = ~np.isfinite(fields[k])
        if bad.any():
            raise AssetError(
                f"{source}: field {k!r} has {int(bad.sum())} non-finite value(s) (first at row {int(np.argmax(bad))})"
            )
    for k in ("scale_0", "scale_1", "scale_2"):  # exp(100) overflows float32: the splat would cover everything
        out = (fields[k] < LOG_SCALE_RANGE[0]) | (fields[k] > LOG_SCALE_RANGE[1])
        if out.any():
            i = int(np.argmax(out))
            raise AssetError(
                f"{source}: field {k!r} (log scale) is {float(fields[k][i]):g} at row {i}, outside "
                f"{list(LOG_SCALE_RANGE)} (frng.apps.asset.LOG_SCALE_RANGE; the object lies in the unit sphere)"
            )
    for k in ("x", "y", "z"):
        if len(fields[k]) and float(np.abs(fields[k]).max()) > MAX_COORDINATE:
            raise AssetError(
                f"{source}: field {k!r} has a position of {float(np.abs(fields[k]).max()):g}, beyond "
                f"{MAX_COORDINATE:g} (frng.apps.asset.MAX_COORDINATE; the object lies in the unit sphere)"
            )
    col = lambda *names: np.stack([np.asarray(fields[k], np.float64) for k in names], axis=1)  # noqa: E731
    t32 = lambda a: torch.from_numpy(np.ascontiguousarray(a, dtype=np.float32))  # noqa: E731
    n = len(fields["x"])
    means = col("x", "y", "z")
    quats = col("rot_0", "rot_1", "rot_2", "rot_3")
    scales = np.exp(col("scale_0", "scale_1", "scale_2"))
    opac = 1.0 / (1.0 + np.exp(-np.asarray(fields["opacity"], np.float64)))
    feats = col(*feat_names) if feat_names else np.zeros((n, 0))
    preview = srgb_decode(np.clip(0.5 + SH_C0 * col("f_dc_0", "f_dc_1", "f_dc_2"), 0.0, 1.0).astype(np.float32))
    features = t32(feats)
    g = Gaussians(t32(means), t32(quats), t32(scales), t32(opac), features)
    return g, features, t32(preview)


# -- asset folder ---------------------------------------------------------------------------------


def save_asset(
    folder: str | os.PathLike,
    gaussians: Gaussians,
    features: np.ndarray | torch.Tensor | None,
    decoder_state: Mapping[str, torch.Tensor],
    meta: Mapping,
    preview_rgb: np.ndarray | torch.Tensor | None = None,
    overwrite: bool = True,
    extra_files: Mapping[str, Callable[[Path], None]] | None = None,
) -> Path:
    """Save a relightable asset folder atomically. Returns the folder path.

    gaussians: N Gaussians (means (N, 3), quats (N, 4) (w, x, y, z), scales (N, 3) > 0, opacities (N,) in (0, 1)).
    features: (N, C) neural features; None -> ``gaussians.features`` reshaped to (N, -1).
    decoder_state: the decoder's ``state_dict()`` (tensors; saved with safetensors, so copies are made
    contiguous and un-shared).
    meta: must contain ``object_id`` (str) and ``decoder`` (dict with at least width, depth, input_encoding);
    ``source_views`` (list) is recommended; any other JSON-serialisable keys are kept in asset.json.
    preview_rgb: optional (N, 3) linear [0, 1] colour (e.g. albedo) shown by 3DGS viewers via f_dc_*.
    overwrite: replace an existing folder (old one removed only after the new one is in place).
    extra_files: file name -> writer(path), called with the path inside the staged folder, e.g. the input light
    and contact sheet ``frng reconstruct`` keeps beside the three asset files (readers ignore other files).
    """

    folder = Path(folder)
    if features is None:
        if gaussians.features is None:
            raise ValueError("save_asset: no features given and gaussians.features is None")
        features = gaussians.features.reshape(len(gaussians), -1)
    if "object_id" not in meta:
        raise ValueError("save_asset: meta needs 'object_id'")
    dec = meta.get("decoder")
    if not isinstance(dec, Mapping) or any(k not in dec for k in REQUIRED_DECODER_KEYS):
        raise ValueError(f"save_asset: meta['decoder'] must be a dict with {list(REQUIRED_DECODER_KEYS)}, got {dec!r}")
    if folder.exists() and not overwrite:
        raise FileExistsError(f"{folder} exists (overwrite=False)")

    fields = gaussians_to_ply_fields(gaussians, features, preview_rgb)
    for k, v in fields.items():
        if not np.isfinite(v).all():
            raise ValueError(f"save_asset: field {k!r} has non-finite values; nothing written")
    state = {}
    for k, v in decoder_state.items():
        if not isinstance(v, torch.Tensor):
            raise ValueError(f"save_asset: decoder_state[{k!r}] is {type(v).__name__}, not a tensor")
        state[k] = v.detach().cpu().contiguous().clone()
    n, c = len(fields["x"]), len(fields) - len(BASE_PROPERTIES)
    info = {
        "format": FORMAT,
        "version": FORMAT_VERSION,
        "num_gaussians": n,
        "feature_dim": c,
        "ply": PLY_FILE,
        "decoder_weights": DECODER_FILE,
        "ply_properties": list(fields),
        "decoder": dict(dec),
        "object_id": str(meta["object_id"]),
        "source_views": list(meta.get("source_views", [])),
        "created": {
            "utc": datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds"),
            "frng_version": _frng_version(),
            **dict(meta.get("created", {})),
        },
        "conventions": {**CONVENTIONS, **dict(meta.get("conventions", {}))},
    }
    info.update({k: v for k, v in meta.items() if k not in info})

    folder.parent.mkdir(parents=True, exist_ok=True)
    tmp = temp_dir(f".tmp-{folder.name}-", folder.parent)
    try:
        write_ply(
            tmp / PLY_FILE,
            fields,
            comments=[
                f"{FORMAT} v{FORMAT_VERSION} object {info['object_id']}",
                "3DGS layout: opacity=logit, scale=log, rot=(w,x,y,z); feat_* = F-RNG features",
            ],
        )
        save_safetensors(state, tmp / DECODER_FILE, {"format": FORMAT, "version": str(FORMAT_VERSION)})
        write_json(tmp / META_FILE, info)
        for name, writer in (extra_files or {}).items():
            if name in (PLY_FILE, DECODER_FILE, META_FILE) or Path(name).name != name:
                raise ValueError(f"save_asset: extra file name {name!r} is reserved or not a plain name")
            writer(tmp / name)
        if folder.exists():
            old = Path(tempfile.mkdtemp(prefix=f".old-{folder.name}-", dir=folder.parent))
            os.replace(folder, old / folder.name)
            os.replace(tmp, folder)
            shutil.rmtree(old, ignore_errors=True)
        else:
            os.replace(tmp, folder)
    finally:
        if tmp.exists():
            shutil.rmtree(tmp, ignore_errors=True)
    return folder


def load_asset(folder: str | os.PathLike) -> tuple[Gaussians, torch.Tensor, dict[str, torch.Tensor], dict]:
    """Load and validate an asset folder.

    Returns (gaussians, features, decoder_state, meta): Gaussians (float32, CPU, ``features`` set to the same
    (N, C) tensor), features (N, C), the decoder's state_dict, and asset.json as a dict (plus
    ``meta["preview_rgb"]``: (N, 3) linear preview colour tensor decoded from f_dc_*).
    Raises :class:`AssetError` naming the file/field for a missing file, wrong format or version, a count
    mismatch between asset.json and the PLY, or non-finite values.
    """
    from safetensors import SafetensorError
    from safetensors.torch import load_file

    from frng import confine

    folder = Path(folder)
    if not folder.is_dir():
        raise AssetError(f"{folder}: asset folder does not exist")
    try:
        meta_path = confine.folder_file(folder, META_FILE, source=folder / META_FILE, field=None)
        if not meta_path.exists():
            raise AssetError(
                f"{meta_path}: missing file (an asset folder holds {META_FILE}, {PLY_FILE}, {DECODER_FILE})"
            )
        meta = read_json(meta_path)
    except ValueError as e:  # confine.UntrustedInputError too: a symlink out of the folder
        raise AssetError(str(e)) from e
    if not isinstance(meta, dict):
        raise AssetError(f"{meta_path}: not a JSON object (a {type(meta).__name__})")
    try:  # the files asset.json names: plain names inside the folder, no symlink out (one check for every loader)
        ply_path = confine.folder_file(folder, meta.get("ply", PLY_FILE), source=meta_path, field="ply")
        dec_path = confine.folder_file(
            folder, meta.get("decoder_weights", DECODER_FILE), source=meta_path, field="decoder_weights"
        )
    except confine.UntrustedInputError as e:
        raise AssetError(str(e)) from None
    for p in (ply_path, dec_path):
        if not p.exists():
            raise AssetError(f"{p}: missing file (an asset folder holds {META_FILE}, {PLY_FILE}, {DECODER_FILE})")
    bad = confine.first_nonfinite(meta)
    if bad is not None:  # json reads NaN / Infinity: a NaN field of view renders all-zero frames
        raise AssetError(f"{meta_path}: field {confine.dotted(bad)!r} is not a finite number (NaN or inf)")
    if meta.get("format") != FORMAT:
        raise AssetError(f"{meta_path}: field 'format' is {meta.get('format')!r}, expected {FORMAT!r}")
    if meta.get("version") != FORMAT_VERSION:
        raise AssetError(
            f"{meta_path}: field 'version' is {meta.get('version')!r}; this frng reads version {FORMAT_VERSION}"
        )
    for k in ("num_gaussians", "feature_dim", "decoder", "object_id"):
        if k not in meta:
            raise AssetError(f"{meta_path}: missing field {k!r}")
    for k, kind in (("num_gaussians", int), ("feature_dim", int), ("decoder", dict), ("object_id", str)):
        if not isinstance(meta[k], kind) or isinstance(meta[k], bool):
            raise AssetError(
                f"{meta_path}: field {k!r} must be a {kind.__name__}, got {type(meta[k]).__name__} {meta[k]!r:.60}"
            )
    if meta["num_gaussians"] < 1:
        raise AssetError(f"{meta_path}: field 'num_gaussians' is {meta['num_gaussians']}; an asset has >= 1 Gaussian")
    if not 0 <= meta["feature_dim"] <= MAX_DECODER_SIZE:
        raise AssetError(f"{meta_path}: field 'feature_dim' is {meta['feature_dim']}; must be 0..{MAX_DECODER_SIZE}")
    for k in ("render", "rig"):
        if meta.get(k) is not None and not isinstance(meta[k], dict):
            raise AssetError(f"{meta_path}: field {k!r} must be an object, got {type(meta[k]).__name__}")

    fields = read_ply(ply_path)
    n = len(fields["x"]) if "x" in fields else len(next(iter(fields.values()), []))
    if n != meta["num_gaussians"]:
        raise AssetError(
            f"{ply_path}: has {n} vertices but {meta_path.name} field 'num_gaussians' says {meta['num_gaussians']}"
        )
    c = sum(k.startswith("feat_") for k in fields)
    if c != meta["feature_dim"]:
        raise AssetError(
            f"{ply_path}: has {c} feat_* properties but {meta_path.name} field 'feature_dim' says {meta['feature_dim']}"
        )
    gaussians, features, preview = ply_fields_to_gaussians(fields, source=str(ply_path))

    try:
        state = load_file(str(dec_path))
    except (SafetensorError, OSError, ValueError) as e:
        raise AssetError(f"{dec_path}: cannot read safetensors ({e})") from e
    for k, v in state.items():
        if not v.is_floating_point():  # int32 weights load into a float decoder as values of 1e8
            raise AssetError(f"{dec_path}: tensor {k!r} has dtype {v.dtype}; decoder weights are floating point")
        if not torch.isfinite(v).all():
            raise AssetError(f"{dec_path}: tensor {k!r} has non-finite values")
    meta["preview_rgb"] = preview
    return gaussians, features, state, meta


# -- rendering an asset (the asset folder and the decoder only: no F-RNG model, no training code) ----------

RENDER_KEY = "render"  # asset.json: {"raster": frng.render.RasterConfig fields, "shading": ShadingConfig fields}
RIG_KEY = "rig"  # asset.json: {"camera_distance", "fov_deg", "resolution"} of the training rig
DECODER_FIELDS = ("feature_dim", "width", "depth", "dir_freqs", "cosine", "attenuation")


def render_settings(raster_cfg, shading_cfg, max_radius_px: float | None = None) -> dict:
    """The ``render`` record of ``asset.json`` from a model's :class:`frng.render.RasterConfig` and
    :class:`frng.render.shading.ShadingConfig` (dataclasses); ``max_radius_px``: the footprint cap the model
    rasterizes with when its raster config leaves it unset (:meth:`frng.model.composed.FRNG.rasterize`)."""
    from dataclasses import asdict

    raster = asdict(raster_cfg)
    if raster.get("max_radius_px") is None:
        raster["max_radius_px"] = max_radius_px
    return {RENDER_KEY: {"raster": raster, "shading": asdict(shading_cfg)}}


class AssetRenderer:
    """Render an asset folder (or a relightable GLB's parts: :func:`frng.apps.gltf_asset.open_renderer`) under any
    environment map, with the asset's own decoder and render settings.

    What :meth:`frng.model.composed.FRNG.rasterize` + :meth:`~frng.model.composed.FRNG.shade` do for the neural head,
    from the asset alone: the Gaussians and features (``gaussians.ply``), the decoder built from ``asset.json``'s
    ``decoder`` (feature_dim, width, depth, dir_freqs, cosine, attenuation, specular) with the weights of
    ``decoder.safetensors``, and the rasterizer / shading settings of ``asset.json``'s ``render`` (the schema's
    defaults when an asset has none, e.g. one written by ``frng relight`` before it recorded them). Shading as the
    model's: with a cosine decoder and ``shading.diffuse: sh`` the Lambertian base in closed form (degree-2 SH
    irradiance) plus the Monte-Carlo residual, plus the specular base when ``decoder.specular`` (prefiltered, or
    a GGX lobe inside the Monte-Carlo pass with ``shading.specular_model: ggx``).
    The light samples are seeded like :meth:`FRNG.light_samples` (a ``generator``'s first draw, else 0), so the
    same asset, light, views and seed give the model's images. Decoding runs in float32 unless ``bf16`` (CUDA).
    """

    def __init__(
        self,
        folder: str | os.PathLike,
        device: str | torch.device = "cpu",
        bf16: bool = False,
        parts: tuple | None = None,
    ):
        """``folder``: an asset folder; or, with ``parts`` = (gaussians, features, decoder state, meta) read from it
        (:func:`frng.apps.gltf_asset.open_renderer` passes a relightable GLB's), the file they came from."""
        from frng.model.coverage import COVERAGE_PREFIX, CoverageHead
        from frng.render import RasterConfig
        from frng.render.shading import NeuralDecoder, ShadingConfig

        self.folder = Path(folder)
        if parts is not None:
            g, features, state, meta = parts
            meta_path = self.folder
        else:
            g, features, state, meta = load_asset(self.folder)
            meta_path = self.folder / META_FILE
        dec = meta["decoder"]
        if dec.get("head", "neural") != "neural":
            raise AssetError(f"{meta_path}: field 'decoder.head' is {dec.get('head')!r}; only neural assets render")
        missing = [k for k in DECODER_FIELDS if k not in dec]
        if missing:
            raise AssetError(f"{meta_path}: field 'decoder' lacks {missing} (needed to build the decoder)")
        for k in ("feature_dim", "width", "depth", "dir_freqs"):
            v = dec[k]
            low = 1 if k in ("width", "depth") else 0
            high = {"depth": 64, "dir_freqs": 32}.get(k, MAX_DECODER_SIZE)
            if isinstance(v, bool) or not isinstance(v, int) or not low <= v <= high:
                raise AssetError(f"{meta_path}: field 'decoder.{k}' must be an integer in {low}..{high}, got {v!r}")
        for k in ("cosine", "attenuation"):
            if not isinstance(dec[k], bool):
                raise AssetError(f"{meta_path}: field 'decoder.{k}' must be true or false, got {dec[k]!r}")
        if int(dec["feature_dim"]) != features.shape[1]:
            raise AssetError(f"{meta_path}: decoder.feature_dim {dec['feature_dim']} != {features.shape[1]} features")
        cov = dec.get("coverage_hidden", 0)  # assets written before the key have no coverage head
        if isinstance(cov, bool) or not isinstance(cov, int) or not 0 <= cov <= MAX_DECODER_SIZE:
            raise AssetError(
                f"{meta_path}: field 'decoder.coverage_hidden' must be an integer in 0..{MAX_DECODER_SIZE}, got {cov!r}"
            )
        self.device = torch.device(device)
        self.meta = meta
        cov_state = {k[len(COVERAGE_PREFIX) :]: v for k, v in state.items() if k.startswith(COVERAGE_PREFIX)}
        try:
            self.decoder = NeuralDecoder(
                int(dec["feature_dim"]),
                int(dec["width"]),
                int(dec["depth"]),
                int(dec["dir_freqs"]),
                cosine=bool(dec["cosine"]),
                attenuation=bool(dec["attenuation"]),
            )
            self.decoder.load_state_dict({k: v for k, v in state.items() if not k.startswith(COVERAGE_PREFIX)})
            self.coverage = CoverageHead(int(dec["feature_dim"]), cov) if cov else None
            if self.coverage is not None:
                self.coverage.load_state_dict(cov_state)
            elif cov_state:
                raise ValueError(f"{len(cov_state)} coverage-head tensors but decoder.coverage_hidden is 0")
        except (RuntimeError, ValueError, TypeError) as e:
            raise AssetError(
                f"{self.folder / DECODER_FILE}: does not fit the decoder of {META_FILE} ({str(e).splitlines()[0]})"
            ) from e
        self.decoder = self.decoder.to(self.device).eval().requires_grad_(False)
        if self.coverage is not None:
            self.coverage = self.coverage.to(self.device).eval().requires_grad_(False)
        self.specular = bool(dec.get("specular", False))
        settings = meta.get(RENDER_KEY) or {}
        try:
            self.raster = RasterConfig.from_dict(dict(settings.get("raster", {})))
            self.shading = ShadingConfig.from_saved(dict(settings.get("shading", {})))
        except (ValueError, KeyError, TypeError, AttributeError) as e:
            raise AssetError(f"{meta_path}: field {RENDER_KEY!r}: {e}") from e
        spp = self.shading.spp_infer
        if isinstance(spp, bool) or not isinstance(spp, int) or not 1 <= spp <= MAX_SPP_INFER:
            raise AssetError(
                f"{meta_path}: field 'render.shading.spp_infer' must be an integer in 1..{MAX_SPP_INFER}, got {spp!r}"
            )
        self.gaussians = Gaussians(
            *(t.to(self.device) for t in (g.means, g.quats, g.scales, g.opacities)), features.to(self.device)
        )
        self.bf16 = bool(bf16) and self.device.type == "cuda"

    @property
    def rig(self) -> dict:
        """The training rig's camera distance, field of view and resolution (``asset.json`` ``rig``), or {}."""
        return dict(self.meta.get(RIG_KEY) or {})

    def rasterize(self, c2w: torch.Tensor, intr: torch.Tensor, height: int, width: int) -> tuple:
        """The feature maps at cameras c2w (V, 4, 4), intr (V, 4): (maps, alpha, c2w, intr) as FRNG.rasterize."""
        from frng.render import rasterize
        from frng.render.shading import COSINE_NORMAL, smooth_normals

        g = self.gaussians
        c2w, intr = c2w.to(self.device).float(), intr.to(self.device).float()
        maps, alpha, _ = rasterize(
            g.means,
            g.quats,
            g.scales,
            g.opacities,
            g.features.float(),
            c2w,
            intr,
            int(height),
            int(width),
            **self.raster.kwargs(),
        )
        if self.decoder.cosine:  # the model's screen-space normal filtering (FRNG.rasterize)
            maps = smooth_normals(maps, alpha, COSINE_NORMAL, self.shading.normal_sigma_px(width))
        if self.coverage is not None:  # the silhouette rim's coverage, as FRNG.rasterize
            maps, alpha = self.coverage(maps, alpha)
        return maps, alpha, c2w, intr

    def shade(
        self, raster: tuple, env: torch.Tensor, spp: int | None = None, generator: torch.Generator | None = None
    ) -> torch.Tensor:
        """Deferred shading under an equirect map (He, We, 3) -> RGBA (V, H, W, 4), linear, premultiplied."""
        from frng.render import envmap
        from frng.render.decoder import shade_decoder

        maps, alpha, c2w, intr = raster
        sc = self.shading
        spp = spp or sc.spp_infer
        env = torch.as_tensor(env).float()
        seed = envmap.sample_seed(generator)
        samples = envmap.sample(envmap.importance_sampler(env.detach().to(self.device)), spp, sc.sampling, seed)
        with torch.no_grad(), torch.autocast(maps.device.type, dtype=torch.bfloat16, enabled=self.bf16):
            rgb = shade_decoder(self.decoder, maps, alpha, c2w, intr, env, samples, sc, self.specular)
        return torch.cat([rgb.float(), alpha], -1)

    def render(
        self,
        env: torch.Tensor,
        c2w: torch.Tensor,
        intr: torch.Tensor,
        height: int,
        width: int,
        spp: int | None = None,
        generator: torch.Generator | None = None,
    ) -> torch.Tensor:
        """:meth:`rasterize` then :meth:`shade`."""
        return self.shade(self.rasterize(c2w, intr, height, width), env, spp, generator)


def _frng_version() -> str:
    from frng import __version__

    return __version__


__all__ = [
    "AssetError",
    "AssetRenderer",
    "RENDER_KEY",
    "RIG_KEY",
    "render_settings",
    "BASE_PROPERTIES",
    "FORMAT",
    "FORMAT_VERSION",
    "SH_C0",
    "gaussians_to_ply_fields",
    "load_asset",
    "ply_fields_to_gaussians",
    "read_ply",
    "read_ply_header",
    "save_asset",
    "write_ply",
]
