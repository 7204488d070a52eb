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
    :func:`staged_output`: a multi-file output is built in a staging folder and moved in at the end, so a failure
    leaves the previous result whole. An existing non-empty ``--out`` that is not a previous output of the same
    command (its :data:`MANIFEST` names it and records the hashes of its files, unchanged) is refused
    (:class:`OutputError`) unless ``force``. A rerun replaces or removes only the files the manifest proves the
    command wrote (recorded hash, unchanged, no symlink: :func:`owned_files`); anything else in the folder is left
    alone, and one in the way is refused unless ``force``. A symlinked ``--out`` is written through, never replaced.
Numbers
    :func:`finite`: arrays entering (cameras, intrinsics, vertices, maps) are finite, of a float type, of the expected
    shape and within bounds; :func:`check_weights`: a state dict's tensors are floating point and finite;
    :func:`first_nonfinite`: where a nested record (a config, an asset.json) holds NaN or inf; :func:`check_record`:
    a model file's architecture record is finite and each size within the schema's maximum (:func:`frng.plan.sections.architecture_bounds`).
Settings files
    :func:`load_yaml`: YAML with a key given twice is refused, naming the key and both lines.
Local servers
    :func:`local_request`: a request to ``frng view`` comes from its own page (Host and Origin 127.0.0.1 /
    localhost on its port), else the reason it is refused.
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


def folder_file(folder: str | os.PathLike, name, *, source, field: str | None) -> Path:
    """A file that an asset folder's metadata names (``asset.json``'s ``ply`` / ``decoder_weights``) or that a loader
    reads from it by its fixed name (``input_light.exr``): ``name`` must be a plain name (:func:`plain_name`) and
    ``folder/name`` must not be a symlink out of the folder (:func:`inside`); else one line naming ``source`` and
    ``field``. The one check every asset loader uses (:func:`frng.apps.asset.load_asset`, ``frng view``)."""
    plain_name(name, source=source, field=field)
    path = Path(folder) / name
    if is_inside(path, folder):
        return path
    where = f"{source}: field {field!r} names {name!r}, which" if field else f"{path}:"
    raise OutsideError(
        f"{where} is a symlink out of the folder {Path(folder).resolve()} (to {path.resolve()}); the files of an "
        f"asset lie in its folder (copy it in)"
    )


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
#
# A command's --out records what it wrote in MANIFEST: {"command": ..., "files": {relative path: sha256}}. The record
# proves ownership only of the files it lists that are still there, unchanged (same bytes, a regular file reached
# through real folders: no symlink): those a rerun may replace or remove. Anything else in the folder -- a file the
# user added, one that changed, one a forged manifest names without its hash, a symlink -- is left alone: a rerun
# that would write over it is refused unless --force. The folder itself is never renamed or replaced: the output is
# staged inside it (a symlinked --out is written through, on the target's file system) and moved in file by file.

_HEX64 = re.compile(r"^[0-9a-f]{64}$")


def _plain_rel(rel) -> bool:
    """A manifest entry: a relative path of plain components (no ``..``, no absolute path, no backslash or NUL)."""
    if not isinstance(rel, str) or not rel or rel.startswith("/") or any(c in rel for c in "\\\0"):
        return False
    parts = rel.split("/")
    return all(p not in ("", ".", "..") for p in parts) and rel != MANIFEST


def file_digest(path: str | os.PathLike) -> str:
    """The sha256 a manifest records of a file (:func:`frng.hashing.file_sha256`)."""
    from frng.hashing import file_sha256

    return file_sha256(path)


def read_manifest(folder: str | os.PathLike) -> dict | None:
    """The :data:`MANIFEST` of a previous output in ``folder`` as ``{"command", "files": {path: sha256},
    "hashed"}``, or None (none, not JSON, no command). A manifest listing names without hashes (written before hashes
    were recorded, or forged), or an entry that is not a plain relative path with a sha256, has ``hashed`` False and
    no files: it proves ownership of nothing."""
    p = Path(folder) / MANIFEST
    try:
        if not p.is_file() or p.is_symlink():
            return None
        m = json.loads(p.read_text())
    except (OSError, ValueError):
        return None
    if not isinstance(m, dict) or not isinstance(m.get("command"), str):
        return None
    files = m.get("files")
    if not isinstance(files, dict):
        return {"command": m["command"], "files": {}, "hashed": False}
    ok = {k: v for k, v in files.items() if _plain_rel(k) and isinstance(v, str) and _HEX64.match(v)}
    if len(ok) != len(files):  # a path out of the folder, a hash that is not one: not a manifest this code wrote
        return {"command": m["command"], "files": {}, "hashed": False}
    return {"command": m["command"], "files": ok, "hashed": True}


def _regular_file(folder: Path, rel: str) -> bool:
    """Whether ``folder/rel`` is a regular file (not a symlink) reached through real folders (no symlink)."""
    import stat

    p = folder
    parts = rel.split("/")
    try:
        for i, part in enumerate(parts):
            p = p / part
            mode = os.lstat(p).st_mode
            if not (stat.S_ISREG(mode) if i == len(parts) - 1 else stat.S_ISDIR(mode)):
                return False
    except OSError:
        return False
    return True


def owned_files(folder: str | os.PathLike, manifest: dict | None) -> dict[str, str]:
    """The files of ``folder`` that ``manifest`` (:func:`read_manifest`) proves a command wrote: listed with a hash,
    a regular file inside the folder (no symlink on the way) and still of that hash."""
    folder = Path(folder)
    if not manifest:
        return {}
    return {
        rel: h for rel, h in manifest["files"].items() if _regular_file(folder, rel) and file_digest(folder / rel) == h
    }


def check_output(out: str | os.PathLike, command: str, force: bool = False, recognise=None) -> None:
    """Refuse (:class:`OutputError`) an ``--out`` that exists and is not a folder, or a non-empty folder that is not a
    previous output of ``command``: its :data:`MANIFEST` names the command and records hashes, and every file it
    records that is still there is unchanged. ``force``: any folder (only what the command writes is replaced).
    ``recognise(folder)``: an output written before manifests recorded hashes, named as such in the refusal."""
    out = Path(out)
    if out.is_symlink() and not out.exists():
        raise OutputError(f"{out}: --out is a dangling symlink")
    if not out.exists():
        return
    if not out.is_dir():
        raise OutputError(f"{out}: --out exists and is not a folder")
    if force or not any(out.iterdir()):
        return
    hint = (
        f"nothing was written (choose an empty or new folder, or pass --force to replace what `frng {command}` "
        f"writes there; other files in it are kept)"
    )
    m = read_manifest(out)
    if m is not None and m["command"] == command and m["hashed"]:
        owned = owned_files(out, m)
        changed = sorted(r for r in m["files"] if os.path.lexists(out / r) and r not in owned)
        if not changed:
            return
        more = f" (and {len(changed) - 1} more)" if len(changed) > 1 else ""
        raise OutputError(
            f"{out}: {changed[0]}{more} changed since `frng {command}` wrote it (its {MANIFEST} records other "
            f"content); {hint}"
        )
    if m is not None and m["command"] != command:
        what = f"a previous output of `frng {m['command']}`"
    elif m is not None or (recognise is not None and recognise(out)):
        what = f"an output of an older frng or not one at all (its {MANIFEST} records no hashes of its files)"
    else:
        what = "not empty"
    raise OutputError(f"{out}: --out is {what} and not a previous output of `frng {command}`; {hint}")


def _files(folder: Path) -> list[str]:
    return sorted(p.relative_to(folder).as_posix() for p in folder.rglob("*") if not p.is_dir() and p.name != MANIFEST)


@contextlib.contextmanager
def staged_output(
    out: str | os.PathLike,
    command: str,
    force: bool = False,
    recognise=None,
    merge: bool = False,
) -> Iterator[Path]:
    """Yield an empty staging folder; when the block succeeds its files are moved into ``out`` (:func:`swap_in`);
    when it fails (an exception, a full disk) the staging folder is removed and ``out`` is as it was.

    ``out`` is checked first (:func:`check_output`). A new ``out`` is staged beside it and renamed; an existing one
    (a symlink to a folder too: written through) is staged inside it (``.tmp-frng-*``, the same file system) and
    never renamed. ``merge``: the previous output's own files are kept where not replaced (outputs that add up, e.g.
    several exported objects in one folder); the manifest then lists both."""
    out = Path(out)
    check_output(out, command, force, recognise)
    if out.exists():
        stage = temp_dir(".tmp-frng-", out)
    else:
        out.parent.mkdir(parents=True, exist_ok=True)
        stage = temp_dir(f".tmp-{out.name}-", out.parent)
    try:
        yield stage
        swap_in(stage, out, command, force=force, merge=merge)
    finally:
        if stage.exists():
            shutil.rmtree(stage, ignore_errors=True)


def _write_manifest(folder: Path, command: str, files: dict[str, str]) -> None:
    text = json.dumps({"command": command, "files": dict(sorted(files.items()))}, indent=2) + "\n"
    (folder / MANIFEST).write_text(text)


def swap_in(stage: Path, out: Path, command: str, force: bool = False, merge: bool = False) -> None:
    """Move the files of ``stage`` into ``out`` and record them (with their hashes) in its :data:`MANIFEST`.

    A new ``out``: ``stage`` is renamed. An existing one: a file the new output writes may replace only a file the
    previous output of ``command`` owns (:func:`owned_files`); any other entry in the way (the user's file, a changed
    one, a symlink, a folder) is refused (:class:`OutputError`, nothing moved) unless ``force``. The previous
    output's owned files that the new one does not write are removed (kept with ``merge``); everything else in
    ``out`` is left alone. Replaced entries are moved aside inside ``out`` first and the moves undone on a failure."""
    files = {rel: file_digest(stage / rel) for rel in _files(stage)}
    if not out.exists():
        _write_manifest(stage, command, files)
        os.replace(stage, out)
        return
    old = read_manifest(out)
    owned = owned_files(out, old) if old is not None and old["command"] == command else {}
    replace, conflicts = set(), set()
    for rel in [*files, MANIFEST]:
        parts, p = rel.split("/"), out
        for i, part in enumerate(parts):
            p = p / part
            if not os.path.lexists(p):
                break
            last, key = i == len(parts) - 1, "/".join(parts[: i + 1])
            if not last and p.is_dir() and not p.is_symlink():
                continue
            if last and not (p.is_dir() and not p.is_symlink()) and (key in owned or key == MANIFEST):
                replace.add(key)
            else:
                conflicts.add(key)
            break
    if conflicts and not force:
        first = sorted(conflicts)[0]
        more = f" (and {len(conflicts) - 1} more)" if len(conflicts) > 1 else ""
        raise OutputError(
            f"{out}: holds {first}{more}, which `frng {command}` would write over and did not write (or which changed "
            f"since); nothing was written (move it away, or pass --force to replace it)"
        )
    stale = set() if merge else {r for r in owned if r not in files}
    if merge:
        files = {**{r: h for r, h in owned.items() if r not in files}, **files}
    _write_manifest(stage, command, files)
    moves = sorted(replace | conflicts | stale)
    moves = [r for r in moves if not any(r.startswith(o + "/") for o in moves)]  # under a moved folder: moved
    aside = temp_dir(".old-frng-", out)
    done: list[tuple[Path, Path]] = []
    made: list[Path] = []
    try:
        for rel in moves:
            dst = aside / rel
            dst.parent.mkdir(parents=True, exist_ok=True)
            os.replace(out / rel, dst)
            done.append((out / rel, dst))
        for rel in [*sorted(r for r in files if (stage / r).exists()), MANIFEST]:
            dst = out / rel
            for d in reversed(dst.parents):
                if d != out and out in d.parents and not d.exists():
                    d.mkdir()
                    made.append(d)
            os.replace(stage / rel, dst)
            done.append((stage / rel, dst))
    except BaseException:
        for src, dst in reversed(done):
            with contextlib.suppress(OSError):
                os.replace(dst, src)
        for d in reversed(made):
            with contextlib.suppress(OSError):
                d.rmdir()
        shutil.rmtree(aside, ignore_errors=True)
        raise
    shutil.rmtree(aside, ignore_errors=True)
    for rel in sorted(stale, reverse=True):  # folders the previous output made and that are now empty
        for d in (out / rel).parents:
            if d == out or out not in d.parents:
                break
            try:
                d.rmdir()
            except OSError:
                break


# -- files of settings ------------------------------------------------------------------------------------------


def load_yaml(text: str):
    """``yaml.safe_load`` that refuses a mapping with a key given twice (plain YAML keeps the last one silently):
    a ``yaml.constructor.ConstructorError`` whose marks give the line of the second one and whose problem names the
    key and the line of the first."""
    import yaml

    class UniqueKeys(yaml.SafeLoader):
        pass

    def mapping(loader, node, deep=False):
        seen: dict = {}
        for key_node, _ in node.value:
            if key_node.tag == "tag:yaml.org,2002:merge" or not isinstance(key_node, yaml.ScalarNode):
                continue
            key = loader.construct_object(key_node, deep=True)
            if key in seen:
                raise yaml.constructor.ConstructorError(
                    "while constructing a mapping",
                    node.start_mark,
                    f"duplicate key {key!r} (first given on line {seen[key].line + 1}; YAML would keep the last "
                    f"silently)",
                    key_node.start_mark,
                )
            seen[key] = key_node.start_mark
        return yaml.SafeLoader.construct_mapping(loader, node, deep)

    UniqueKeys.add_constructor(yaml.resolver.BaseResolver.DEFAULT_MAPPING_TAG, mapping)
    return yaml.load(text, Loader=UniqueKeys)  # noqa: S506 -- a SafeLoader


# -- local servers ----------------------------------------------------------------------------------------------


def local_request(headers, port: int, names: tuple[str, ...] = ("127.0.0.1", "localhost")) -> str | None:
    """Why an HTTP request or websocket handshake to a server on ``127.0.0.1:port`` does not come from that server's
    own page, or None when it does: exactly one ``Host``, one of ``names`` with ``:port`` (a DNS-rebound name,
    ``Host: evil.example``, is refused); an ``Origin``, where sent (browsers send one with every websocket handshake
    and cross-origin request), ``http://NAME:port`` of the same names. A client that sends no Origin (not a browser,
    or a plain page load) passes. ``headers``: a mapping with ``get_all`` (``websockets.datastructures.Headers``,
    ``email.message.Message``) or ``get``."""
    hosts = {f"{n}:{int(port)}" for n in names} | (set(names) if int(port) == 80 else set())

    def values(key: str) -> list[str]:
        if hasattr(headers, "get_all"):
            return [str(v) for v in headers.get_all(key) or []]
        v = headers.get(key)
        return [] if v is None else [str(v)]

    host, origin = values("Host"), values("Origin")
    if len(host) != 1 or host[0].strip().lower() not in hosts:
        shown = host[0][:80] if len(host) == 1 else f"{len(host)} Host headers"
        return f"Host {shown!r} is not the viewer's own (http://{names[0]}:{port}); a foreign or DNS-rebound name"
    if len(origin) > 1 or (origin and origin[0].strip().lower() not in {f"http://{h}" for h in hosts}):
        shown = origin[0][:80] if len(origin) == 1 else f"{len(origin)} Origin headers"
        return f"Origin {shown!r} is not the viewer's own page (http://{names[0]}:{port})"
    return None


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


MAX_CAMERA_DISTANCE = 1e6  # a camera farther from the world origin is refused (1e30 gave an asset)
FOV_RANGE_DEG = (0.01, 179.0)  # a camera's horizontal / vertical field of view (fx = 2.6e-14 was stored)


def check_camera(c2w, intr, size=None, *, source, field: str) -> None:
    """A camera from a file, before anything renders or fits with it: ``c2w`` a finite 4 x 4 whose rotation is not
    singular and whose centre is within :data:`MAX_CAMERA_DISTANCE` of the origin; ``intr`` (fx, fy, cx, cy) finite,
    fx, fy > 0 and, where the image ``size`` (W, H) is known, fields of view within :data:`FOV_RANGE_DEG` and the
    principal point within ten image sizes of the image. Else one line naming ``source`` and ``field``."""
    m = finite(c2w, source=source, field=f"{field} c2w", shape=(4, 4))
    det = float(np.linalg.det(m[:3, :3]))
    if not abs(det) > 1e-6:
        raise NonFiniteError(f"{_where(source, field)}: its rotation is singular (det {det:.3g})")
    centre = float(np.linalg.norm(m[:3, 3]))
    if centre > MAX_CAMERA_DISTANCE:
        raise NonFiniteError(
            f"{_where(source, field)}: camera is {centre:.3g} from the origin (at most {MAX_CAMERA_DISTANCE:g}, "
            f"frng.confine.MAX_CAMERA_DISTANCE)"
        )
    k = finite(intr, source=source, field=f"{field} intrinsics", shape=(4,))
    if not (k[0] > 0 and k[1] > 0):
        raise NonFiniteError(f"{_where(source, field)}: focal lengths must be > 0, got fx={k[0]:g}, fy={k[1]:g}")
    if size is not None:
        lo, hi = FOV_RANGE_DEG
        for axis, (f, n) in enumerate(zip(k[:2], size)):
            fov = math.degrees(2.0 * math.atan(0.5 * float(n) / float(f)))
            if not lo <= fov <= hi:
                raise NonFiniteError(
                    f"{_where(source, field)}: field of view {fov:.4g} deg ({'xy'[axis]}: focal {f:.3g} px for "
                    f"{n} px) is outside [{lo:g}, {hi:g}] deg"
                )
        if not (abs(k[2]) <= 10 * size[0] and abs(k[3]) <= 10 * size[1]):
            raise NonFiniteError(f"{_where(source, field)}: principal point ({k[2]:g}, {k[3]:g}) is far off the image")


MAX_ARCH_SIZE = 8192  # an integer of a model file's architecture record whose name the schema does not bound


def first_nonfinite(value, path: tuple = ()) -> tuple | None:
    """The path (keys and list indices) of the first NaN or inf float in nested dicts / lists / tuples, or None."""
    if isinstance(value, float):
        return None if math.isfinite(value) else path
    if isinstance(value, Mapping):
        items = value.items()
    elif isinstance(value, (list, tuple)):
        items = enumerate(value)
    else:
        return None
    for k, v in items:
        found = first_nonfinite(v, (*path, k))
        if found is not None:
            return found
    return None


def dotted(path: tuple) -> str:
    """``("a", 0, "b")`` -> ``"a[0].b"``, the way messages name a key."""
    return ".".join(f"[{p}]" if isinstance(p, int) else str(p) for p in path).replace(".[", "[") or "<root>"


def check_record(
    record: Mapping,
    *,
    source,
    field: str,
    bounds: Mapping[str, tuple[float | None, float | None]] | None = None,
    int_max: int | None = MAX_ARCH_SIZE,
) -> None:
    """The numbers of a record read from a file (a model file's architecture, an asset's metadata): every number
    finite; one whose key ``bounds`` names within its (minimum, maximum) (a None minimum: 0 for an integer); any
    other integer within 0..``int_max`` (None: unbounded). Nested mappings and lists are walked. Else one line naming ``source`` and the key: a crafted
    ``hidden: 300000`` is refused before a model of that size is allocated."""
    bounds = bounds or {}
    for k, v in record.items():
        key = f"{field}.{k}"
        if isinstance(v, Mapping):
            check_record(v, source=source, field=key, bounds=bounds, int_max=int_max)
            continue
        bad = first_nonfinite(v)
        if bad is not None:
            raise NonFiniteError(f"{_where(source, dotted((key, *bad)))} is not a finite number (NaN or inf)")
        if isinstance(v, bool) or not isinstance(v, (int, float)):
            continue
        lo, hi = bounds.get(str(k), (None, int_max if isinstance(v, int) else None))
        lo = 0 if lo is None and isinstance(v, int) else lo  # sizes are not negative
        if (lo is not None and v < lo) or (hi is not None and v > hi):
            raise NonFiniteError(
                f"{_where(source, key)} is {v!r}; must be in {'-inf' if lo is None else f'{lo:g}'}.."
                f"{'inf' if hi is None else f'{hi:g}'}"
            )


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
    # Radiance RGBE; a float TIFF named .hdr is what the benchmark writers wrote before frng.io.write_hdr (frng.io.read_hdr)
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
    "check_camera",
    "check_id",
    "check_image_size",
    "check_mesh_references",
    "gltf_nonfinite_position",
    "mesh_references",
    "owned_files",
    "check_output",
    "check_record",
    "check_weights",
    "dotted",
    "first_nonfinite",
    "load_yaml",
    "MAX_ARCH_SIZE",
    "MAX_CAMERA_DISTANCE",
    "file_digest",
    "finite",
    "folder_file",
    "inside",
    "is_inside",
    "local_request",
    "member",
    "plain_name",
    "read_manifest",
    "safe_id",
    "staged_output",
    "swap_in",
]
