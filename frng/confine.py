"""Safety rules for data from outside (benchmark folders, asset packs, photos, model files): one place, used by every
reader and every command that writes a user-named folder (docs/reliability.md).

Paths
    :func:`inside` / :func:`member`: a path a file names (``file_path``, ``scene_name``, ``map_Kd``, a glTF URI, a
    symlink in the folder) is resolved (symlinks too) and must stay inside the folder the user gave; anything else
    is an :class:`OutsideError` naming the file and the field, unless the caller passes ``allow_outside`` (the
    commands' ``--allow-outside``).
Names
    :func:`safe_id`: ids and scene names taken from files are sanitised like object ids, ``[a-z0-9_-]``, before
    they become part of a path; :func:`plain_name` refuses anything that is not one plain path component;
    :func:`check_id`: a user-given id (``--id``) must already be one.
Outputs
    :func:`staged_output`: a multi-file output is built in a staging folder beside the target and swapped in at the
    end, so a failure leaves the previous result whole. An existing non-empty ``--out`` that is not a previous output
    of the same command (its :data:`MANIFEST` says so) is refused (:class:`OutputError`) unless ``force``; replacing
    removes only what the command wrote before (the manifest's files): anything else in the folder is kept.
Numbers
    :func:`finite`: arrays entering (cameras, intrinsics, vertices, maps) are finite, of a float type, of the expected
    shape and within bounds; :func:`check_weights`: a state dict's tensors are floating point and finite.
Images
    :func:`check_image_size`: an image's pixel count is bounded (:data:`MAX_IMAGE_PIXELS`) from its header, before it
    is decoded; a file whose content is not the image format its name says is one line.

Every error here is a :class:`UntrustedInputError` (a ``ValueError``) whose message is one line naming the file.
"""

from __future__ import annotations

import contextlib
import json
import math
import os
import re
import shutil
import tempfile
import warnings
from collections.abc import Iterator, Mapping
from pathlib import Path

import numpy as np

MANIFEST = ".frng-output.json"  # what a command wrote into its --out folder (staged_output)
MAX_IMAGE_PIXELS = 100_000_000  # 10000 x 10000: an image with more pixels is refused before it is decoded
ALLOW_OUTSIDE_HINT = "pass --allow-outside to read it anyway"


class UntrustedInputError(ValueError):
    """A file from outside (or a user-named output folder) breaks a safety rule; the message names the file."""


class OutsideError(UntrustedInputError):
    """A path a file names resolves outside the folder the user gave."""


class OutputError(UntrustedInputError):
    """An output folder that this command would destroy: not empty and not a previous output of the command."""


class NonFiniteError(UntrustedInputError):
    """An array entering from a file is non-finite, of the wrong type or shape, or out of its bounds."""


def current_umask() -> int:
    """The process's umask: from ``/proc/self/status`` on Linux (no side effect), else by setting and restoring
    it (Python has no read-only call; another thread creating a file in between would see 022)."""
    try:
        with open("/proc/self/status") as f:
            for line in f:
                if line.startswith("Umask:"):
                    return int(line.split()[1], 8)
    except (OSError, ValueError, IndexError):
        pass
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def temp_dir(prefix: str, dir: str | os.PathLike) -> Path:
    """``tempfile.mkdtemp`` with the permissions an ordinary ``mkdir`` would give (0777 minus the umask) instead
    of 0700, for staging folders that are renamed into place (results are shared on clusters)."""
    tmp = Path(tempfile.mkdtemp(prefix=prefix, dir=dir))
    os.chmod(tmp, 0o777 & ~current_umask())
    return tmp


# -- paths ------------------------------------------------------------------------------------------------------


def _where(source, field) -> str:
    return f"{source}: field {field!r}" if field else f"{source}"


def is_inside(path: str | os.PathLike, root: str | os.PathLike) -> bool:
    """Whether ``path`` resolves (symlinks followed) to ``root`` or below it (``root`` resolved too)."""
    p, r = Path(path).resolve(), Path(root).resolve()
    return p == r or r in p.parents


def inside(
    path: str | os.PathLike,
    root: str | os.PathLike,
    *,
    source: str | os.PathLike | None = None,
    field: str | None = None,
    allow_outside: bool = False,
) -> Path:
    """``path`` unchanged (not resolved: messages and records keep the user's spelling) when it resolves inside
    ``root``; else an :class:`OutsideError` naming ``source`` (the file that named it; default ``path``) and
    ``field``. ``allow_outside``: no check."""
    path = Path(path)
    if allow_outside or is_inside(path, root):
        return path
    resolved = path.resolve()
    link = " (through a symlink)" if resolved != Path(os.path.abspath(path)) else ""
    if source is None:  # a file found in the folder (listed, not named): itself the culprit
        raise OutsideError(
            f"{path}: is outside {Path(root).resolve()}{link} (resolves to {resolved}); {ALLOW_OUTSIDE_HINT}"
        )
    raise OutsideError(
        f"{_where(source, field)} names {path}, which is outside {Path(root).resolve()}{link} "
        f"(resolves to {resolved}); {ALLOW_OUTSIDE_HINT}"
    )


def member(
    root: str | os.PathLike,
    ref,
    *,
    source: str | os.PathLike,
    field: str,
    base: str | os.PathLike | None = None,
    suffix: str = "",
    allow_outside: bool = False,
) -> Path:
    """The path ``{base}/{ref}{suffix}`` a file names (``base`` defaults to ``root``), checked: ``ref`` must be a
    non-empty string (else one line naming ``source`` and ``field``) and the path must resolve inside ``root``
    (:func:`inside`)."""
    if not isinstance(ref, str) or not ref or "\0" in ref:
        raise UntrustedInputError(f"{_where(source, field)} must be a non-empty path string, got {ref!r}")
    return inside(
        Path(base if base is not None else root) / (ref + suffix),
        root,
        source=source,
        field=field,
        allow_outside=allow_outside,
    )


def plain_name(value, *, source, field: str) -> str:
    """``value`` when it is one plain path component (a non-empty string, no ``/`` or ``\\``, not ``.`` or ``..``,
    no NUL), else one line naming ``source`` and ``field``."""
    if not isinstance(value, str) or not value or value in (".", "..") or any(c in value for c in "/\\\0"):
        raise UntrustedInputError(f"{_where(source, field)} must be a plain name (no path parts), got {value!r}")
    return value


_ID = re.compile(r"^[a-z0-9_-]+$")


def safe_id(value, *, source, field: str) -> str:
    """A name from a file made safe to join into a path the way object ids are: lower-cased, every run of
    characters outside ``[a-z0-9_-]`` replaced by ``_``, leading/trailing ``_`` stripped. A name already of that form
    is returned unchanged; a non-string or one with nothing left is one line naming ``source`` and ``field``."""
    if isinstance(value, bool) or not isinstance(value, (str, int)):
        raise UntrustedInputError(f"{_where(source, field)} must be a string, got {type(value).__name__} {value!r}")
    value = str(value)
    if _ID.match(value):
        return value
    out = re.sub(r"[^a-z0-9_-]+", "_", value.lower()).strip("_")
    if not out or out.strip("-") == "":
        raise UntrustedInputError(f"{_where(source, field)}: {value!r} has no usable characters ([a-z0-9_-])")
    return out


def check_id(value: str, what: str = "--id") -> str:
    """A user-given id: ``[a-z0-9_-]+`` (no path parts, no upper case), else one line."""
    if not isinstance(value, str) or not _ID.match(value):
        raise UntrustedInputError(
            f"{what} {value!r}: ids are lower-case letters, digits, '_' and '-' only (no path parts)"
        )
    return value


# -- outputs ----------------------------------------------------------------------------------------------------


def read_manifest(folder: str | os.PathLike) -> dict | None:
    """The :data:`MANIFEST` of a previous output in ``folder`` (``{"command", "files"}``), or None."""
    p = Path(folder) / MANIFEST
    try:
        m = json.loads(p.read_text())
    except (OSError, ValueError):
        return None
    if not isinstance(m, dict) or not isinstance(m.get("command"), str) or not isinstance(m.get("files"), list):
        return None
    return m


def check_output(out: str | os.PathLike, command: str, force: bool = False, recognise=None) -> None:
    """Refuse (:class:`OutputError`) an ``--out`` that exists and is not a folder, or a non-empty folder that is not a
    previous output of ``command`` (its :data:`MANIFEST`, or ``recognise(folder)`` true: outputs written before
    manifests existed), unless ``force``."""
    out = Path(out)
    if out.is_symlink() and not out.exists():
        raise OutputError(f"{out}: --out is a dangling symlink")
    if not out.exists():
        return
    if not out.is_dir():
        raise OutputError(f"{out}: --out exists and is not a folder")
    if force or not any(out.iterdir()):
        return
    m = read_manifest(out)
    if m is not None and m["command"] == command:
        return
    if m is None and recognise is not None and recognise(out):
        return
    what = f"a previous output of `frng {m['command']}`" if m else "not empty"
    raise OutputError(
        f"{out}: --out is {what} and not a previous output of `frng {command}`; nothing was written "
        f"(choose an empty or new folder, or pass --force to replace what `frng {command}` writes there; "
        f"other files in it are kept)"
    )


def _files(folder: Path) -> list[str]:
    return sorted(str(p.relative_to(folder)) for p in folder.rglob("*") if not p.is_dir() and p.name != MANIFEST)


@contextlib.contextmanager
def staged_output(
    out: str | os.PathLike,
    command: str,
    force: bool = False,
    recognise=None,
    manifest: bool = True,
    merge: bool = False,
) -> Iterator[Path]:
    """Yield an empty staging folder beside ``out``; when the block succeeds it becomes ``out`` (see the module
    docstring); when it fails (an exception, a full disk) the staging folder is removed and ``out`` is as it was.

    ``out`` is checked first (:func:`check_output`). On success the staged files are recorded in :data:`MANIFEST`
    (unless ``manifest`` is False) and swapped in: a previous ``out`` is moved aside, the staged folder renamed to
    ``out``, and every entry of the previous folder that the command did not write (not in its manifest; with
    ``force`` on a foreign folder, everything) and that the new output does not replace is moved back in.
    ``merge``: the previous output's own files are kept too where not replaced (outputs that add up, e.g. several
    exported objects in one folder); the manifest then lists both."""
    out = Path(out)
    check_output(out, command, force, recognise)
    out.parent.mkdir(parents=True, exist_ok=True)
    stage = temp_dir(f".tmp-{out.name}-", out.parent)
    try:
        yield stage
        written = _files(stage)
        if manifest:
            if merge and (old := read_manifest(out)) is not None:
                written = sorted(set(written) | {str(f) for f in old["files"]})
            (stage / MANIFEST).write_text(json.dumps({"command": command, "files": written}, indent=2) + "\n")
        swap_in(stage, out, merge)
    finally:
        if stage.exists():
            shutil.rmtree(stage, ignore_errors=True)


def swap_in(stage: Path, out: Path, merge: bool = False) -> None:
    """Rename ``stage`` to ``out``; a previous ``out`` keeps the entries its command did not write (all entries not
    replaced, with ``merge``; :func:`staged_output`)."""
    if not out.exists():
        os.replace(stage, out)
        return
    old_m = read_manifest(out)
    prev = set(old_m["files"]) if old_m and not merge else set()
    aside = temp_dir(f".old-{out.name}-", out.parent)
    old = aside / out.name
    os.replace(out, old)
    try:
        os.replace(stage, out)
    except BaseException:
        os.replace(old, out)
        shutil.rmtree(aside, ignore_errors=True)
        raise
    _carry(old, out, prev, Path("."))
    shutil.rmtree(aside, ignore_errors=True)


def _carry(old: Path, new: Path, prev: set[str], rel: Path) -> None:
    """Move back every entry of ``old`` (relative ``rel``) that the previous command did not write."""
    for entry in sorted((old / rel).iterdir()):
        r = rel / entry.name
        key = str(r) if str(rel) != "." else entry.name
        if entry.name == MANIFEST and str(rel) == ".":
            continue
        target = new / r
        if entry.is_dir() and not entry.is_symlink():
            if any(p.startswith(key + "/") for p in prev):  # holds files the command wrote: look inside
                _carry(old, new, prev, r)
            elif not target.exists():
                target.parent.mkdir(parents=True, exist_ok=True)
                os.replace(entry, target)
            continue
        if key in prev or target.exists():
            continue
        target.parent.mkdir(parents=True, exist_ok=True)
        os.replace(entry, target)


# -- numbers ----------------------------------------------------------------------------------------------------


def finite(
    value,
    *,
    source,
    field: str,
    shape: tuple | None = None,
    minimum: float | None = None,
    maximum: float | None = None,
    positive: bool = False,
) -> np.ndarray:
    """``value`` as a float64 array, checked: numeric (bools and strings refused), ``shape`` (``None`` entries
    match any size), finite, ``> 0`` where ``positive``, within [``minimum``, ``maximum``]. Else one line naming
    ``source`` and ``field``."""
    try:
        arr = np.asarray(value)
        if arr.dtype == bool or arr.dtype.kind not in "iuf":
            raise TypeError
        arr = arr.astype(np.float64)
    except (TypeError, ValueError):
        raise NonFiniteError(f"{_where(source, field)} must be numbers, got {str(value)[:80]!r}") from None
    if shape is not None and (
        arr.ndim != len(shape) or any(s is not None and s != n for s, n in zip(shape, arr.shape))
    ):
        want = "x".join("N" if s is None else str(s) for s in shape) or "a scalar"
        raise NonFiniteError(f"{_where(source, field)} must be {want}, got shape {arr.shape}")
    if not np.isfinite(arr).all():
        raise NonFiniteError(f"{_where(source, field)} has non-finite values (NaN or inf)")
    if positive and not (arr > 0).all():
        raise NonFiniteError(f"{_where(source, field)} must be > 0, got {arr.min():g}")
    if minimum is not None and arr.size and arr.min() < minimum:
        raise NonFiniteError(f"{_where(source, field)} must be >= {minimum:g}, got {arr.min():g}")
    if maximum is not None and arr.size and arr.max() > maximum:
        raise NonFiniteError(f"{_where(source, field)} must be <= {maximum:g}, got {arr.max():g}")
    return arr


def angle(value, *, source, field: str) -> float:
    """A field of view in radians: a finite number in (0, pi)."""
    a = float(finite(value, source=source, field=field, shape=()))
    if not 0.0 < a < math.pi:
        raise NonFiniteError(f"{_where(source, field)} must be a field of view in (0, pi) radians, got {a:g}")
    return a


def check_weights(state: Mapping, *, source, what: str = "state dict") -> None:
    """Every tensor of ``state`` (a state dict) is floating point and finite; else one line naming ``source`` and
    the key (integer weights would render values of 1e8; NaN weights render NaN)."""
    import torch

    if not isinstance(state, Mapping):
        raise UntrustedInputError(f"{source}: {what} is a {type(state).__name__}, not a dict of tensors")
    for k, v in state.items():
        if not isinstance(v, torch.Tensor):
            raise UntrustedInputError(f"{source}: {what} entry {k!r} is a {type(v).__name__}, not a tensor")
        if not v.is_floating_point():
            raise UntrustedInputError(f"{source}: {what} entry {k!r} has dtype {v.dtype}; weights are floating point")
        if not torch.isfinite(v).all():
            raise UntrustedInputError(f"{source}: {what} entry {k!r} has non-finite values (NaN or inf)")


# -- images -----------------------------------------------------------------------------------------------------

_MAGIC = {
    ".png": (b"\x89PNG\r\n\x1a\n",),
    ".jpg": (b"\xff\xd8\xff",),
    ".jpeg": (b"\xff\xd8\xff",),
    ".exr": (b"\x76\x2f\x31\x01",),
    # imageio reads an .hdr by its content; frng.benchmarks.common.write_hdr (imageio) writes float TIFF bytes
    ".hdr": (b"#?RADIANCE", b"#?RGBE", b"II*\x00", b"MM\x00*"),
}


def check_image_size(path: str | os.PathLike, max_pixels: int = MAX_IMAGE_PIXELS) -> tuple[int, int] | None:
    """Before decoding: the file starts like the format its suffix names (else one line: a text file named .png),
    and its header's width x height is at most ``max_pixels`` (else one line). Returns (W, H) where the header was
    read, else None (a format without a check here)."""
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in _MAGIC:
        return None
    try:
        with open(path, "rb") as f:
            head = f.read(64)
    except OSError as e:
        raise UntrustedInputError(f"{path}: cannot read ({e.strerror or e})") from None
    if not any(head.startswith(m) for m in _MAGIC[suffix]):
        raise UntrustedInputError(f"{path}: not a {suffix[1:].upper()} file (its first bytes are {head[:8]!r})")
    size = None
    if head[:4] in (b"II*\x00", b"MM\x00*"):
        size = _tiff_size(path)
    elif suffix in (".png", ".jpg", ".jpeg"):
        from PIL import Image

        try:
            with warnings.catch_warnings():  # PIL warns of a "decompression bomb": bounded below, with the file named
                warnings.simplefilter("ignore", Image.DecompressionBombWarning)
                with Image.open(path) as im:
                    size = im.size
        except Exception as e:  # noqa: BLE001 -- PIL raises many kinds for a corrupt header
            raise UntrustedInputError(f"{path}: cannot read the image header ({type(e).__name__}: {e})") from None
    elif suffix == ".hdr":  # Radiance
        size = _hdr_size(path)
    elif suffix == ".exr":
        size = _exr_size(path)
    if size is not None and size[0] * size[1] > max_pixels:
        raise UntrustedInputError(
            f"{path}: {size[0]}x{size[1]} image has more than {max_pixels} pixels (the limit, "
            f"frng.confine.MAX_IMAGE_PIXELS); downscale it first"
        )
    return size


def _hdr_size(path: Path) -> tuple[int, int] | None:
    with open(path, "rb") as f:
        for _ in range(64):
            line = f.readline(4096)
            if not line:
                break
            m = re.match(rb"^([-+])Y (\d+) ([-+])X (\d+)\s*$", line)
            if m:
                return int(m.group(4)), int(m.group(2))
    raise UntrustedInputError(f"{path}: truncated or corrupt Radiance HDR (no resolution line in its header)")


def _tiff_size(path: Path) -> tuple[int, int] | None:
    try:
        import tifffile

        with tifffile.TiffFile(path) as t:
            shape = t.pages[0].shape
        return int(shape[1]), int(shape[0])
    except Exception:  # noqa: BLE001 -- the reader names a corrupt file
        return None


def _exr_size(path: Path) -> tuple[int, int] | None:
    try:
        import OpenEXR

        with OpenEXR.File(str(path), header_only=True) as f:
            sizes = []
            for part in f.parts:
                (x0, y0), (x1, y1) = (np.asarray(v) for v in part.header["dataWindow"])
                sizes.append((int(x1) - int(x0) + 1, int(y1) - int(y0) + 1))
    except Exception:  # noqa: BLE001 -- the reader names a corrupt file
        return None
    return max(sizes, key=lambda s: s[0] * s[1]) if sizes else None


# -- meshes (own assets imported in Blender; pure Python, checked before Blender opens the file) ----------------

_MTL_MAPS = ("map_", "bump", "disp", "decal", "refl", "norm")


def mesh_references(path: str | os.PathLike) -> list[tuple[str, str, str]]:
    """The files a mesh file names, as (file naming it, field, reference as written): an OBJ's ``mtllib`` and, in
    each of those MTLs, its texture statements (``map_Kd``, ``bump``, ``disp``, ``refl``, ``norm``, ...: every token
    after the keyword, and the whole remainder, since names may hold spaces); a glTF's (or GLB's JSON chunk's)
    ``buffers[].uri`` and ``images[].uri`` (``data:`` URIs excluded; URI-decoded). Other formats name none."""
    path = Path(path)
    suffix = path.suffix.lower()
    out: list[tuple[str, str, str]] = []
    if suffix == ".obj":
        for no, line in enumerate(_text(path).splitlines(), 1):
            words = line.split(None, 1)
            if len(words) == 2 and words[0] == "mtllib":
                for ref in _candidates(words[1]):
                    out.append((str(path), f"line {no} mtllib", ref))
                    mtl = path.parent / ref
                    if is_inside(mtl, path.parent) and mtl.is_file():
                        out += _mtl_references(mtl)
    elif suffix in (".gltf", ".glb"):
        doc = _gltf_json(path)
        for key in ("buffers", "images"):
            for i, item in enumerate(doc.get(key) or []):
                uri = item.get("uri") if isinstance(item, dict) else None
                if isinstance(uri, str) and not uri.startswith("data:"):
                    from urllib.parse import unquote

                    out.append((str(path), f"{key}[{i}].uri", unquote(uri)))
    return out


def _text(path: Path) -> str:
    return path.read_bytes().decode("utf-8", "replace")


def _candidates(rest: str) -> list[str]:
    rest = rest.strip()
    tokens = rest.split()
    return list(dict.fromkeys([rest, *tokens])) if rest else []


def _mtl_references(mtl: Path) -> list[tuple[str, str, str]]:
    out = []
    for no, line in enumerate(_text(mtl).splitlines(), 1):
        words = line.split(None, 1)
        if len(words) == 2 and words[0].lower().startswith(_MTL_MAPS):
            out += [(str(mtl), f"line {no} {words[0]}", ref) for ref in _candidates(words[1])]
    return out


def _gltf_json(path: Path) -> dict:
    data = path.read_bytes()
    try:
        if path.suffix.lower() == ".glb":
            if len(data) < 20 or data[:4] != b"glTF":
                return {}
            n = int.from_bytes(data[12:16], "little")
            if data[16:20] != b"JSON":
                return {}
            doc = json.loads(data[20 : 20 + n])
        else:
            doc = json.loads(data)
    except ValueError:
        return {}  # not JSON: the importer names the file
    return doc if isinstance(doc, dict) else {}


def check_mesh_references(
    path: str | os.PathLike, root: str | os.PathLike | None = None, allow_outside: bool = False
) -> None:
    """Every existing file the mesh ``path`` names (:func:`mesh_references`) must resolve inside ``root`` (default: the
    mesh's folder), symlinks resolved; else an :class:`OutsideError` naming the file and the field. Relative
    references are taken from the naming file's folder (the OBJ's, the MTL's, the glTF's), as the importers do. A
    reference to a file that does not exist (an author's absolute path) reads nothing and passes: the importer skips
    it and :func:`frng.blender.materials.adopt` looks for it inside the asset's folders."""
    if allow_outside:
        return
    path = Path(path)
    root = Path(root) if root is not None else path.parent
    for naming, field, ref in mesh_references(path):
        target = Path(naming).parent / ref
        if not is_inside(target, root) and target.exists():  # a missing one reads nothing (the importer skips it)
            raise OutsideError(
                f"{naming}: {field} names {ref!r}, which is outside the asset folder {root.resolve()} "
                f"(resolves to {target.resolve()}); copy the file into the asset's folder"
            )


def gltf_nonfinite_position(path: str | os.PathLike) -> str | None:
    """Where a glTF/GLB's ``POSITION`` accessors hold a NaN/inf (``"meshes[0].primitives[0] POSITION vertex 3"``),
    else None (Blender's importer turns them into 0 silently). Float VEC3 accessors in the GLB's BIN chunk, a
    ``data:`` URI or a file beside it are read; others are left to the check after import."""
    import base64

    path = Path(path)
    data = path.read_bytes() if path.suffix.lower() == ".glb" else b""
    doc = _gltf_json(path)
    bins: dict[int, bytes] = {}

    def buffer(i: int) -> bytes | None:
        if i in bins:
            return bins[i]
        bufs = doc.get("buffers") or []
        if not 0 <= i < len(bufs) or not isinstance(bufs[i], dict):
            return None
        uri = bufs[i].get("uri")
        raw = None
        if uri is None and data:  # the GLB's BIN chunk
            n = int.from_bytes(data[12:16], "little")
            off = 20 + n
            if len(data) >= off + 8 and data[off + 4 : off + 8] == b"BIN\0":
                m = int.from_bytes(data[off : off + 4], "little")
                raw = data[off + 8 : off + 8 + m]
        elif isinstance(uri, str) and uri.startswith("data:") and "," in uri:
            try:
                raw = base64.b64decode(uri.split(",", 1)[1])
            except ValueError:
                raw = None
        elif isinstance(uri, str):
            from urllib.parse import unquote

            f = path.parent / unquote(uri)
            raw = f.read_bytes() if is_inside(f, path.parent) and f.is_file() else None
        bins[i] = raw
        return raw

    try:
        accessors, views = doc.get("accessors") or [], doc.get("bufferViews") or []
        for mi, mesh in enumerate(doc.get("meshes") or []):
            for pi, prim in enumerate(mesh.get("primitives") or []):
                ai = (prim.get("attributes") or {}).get("POSITION")
                if not isinstance(ai, int) or not 0 <= ai < len(accessors):
                    continue
                acc = accessors[ai]
                if acc.get("componentType") != 5126 or acc.get("type") != "VEC3" or "bufferView" not in acc:
                    continue
                view = views[acc["bufferView"]]
                raw = buffer(int(view.get("buffer", 0)))
                if raw is None:
                    continue
                count = int(acc.get("count", 0))
                stride = int(view.get("byteStride") or 12)
                start = int(view.get("byteOffset", 0)) + int(acc.get("byteOffset", 0))
                if count <= 0 or start + stride * (count - 1) + 12 > len(raw):
                    continue
                rows = np.lib.stride_tricks.as_strided(
                    np.frombuffer(raw, dtype=np.uint8, offset=start), shape=(count, 12), strides=(stride, 1)
                )
                xyz = np.ascontiguousarray(rows).view("<f4").reshape(count, 3)
                bad = ~np.isfinite(xyz).all(axis=1)
                if bad.any():
                    return f"meshes[{mi}].primitives[{pi}] POSITION vertex {int(np.argmax(bad))}"
    except (TypeError, ValueError, KeyError, IndexError, AttributeError):
        return None  # a malformed file: the importer names it
    return None


__all__ = [
    "ALLOW_OUTSIDE_HINT",
    "MANIFEST",
    "MAX_IMAGE_PIXELS",
    "NonFiniteError",
    "OutputError",
    "OutsideError",
    "UntrustedInputError",
    "angle",
    "check_id",
    "check_image_size",
    "check_mesh_references",
    "gltf_nonfinite_position",
    "mesh_references",
    "check_output",
    "check_weights",
    "finite",
    "inside",
    "is_inside",
    "member",
    "plain_name",
    "read_manifest",
    "safe_id",
    "staged_output",
    "swap_in",
]
