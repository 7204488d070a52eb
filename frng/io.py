"""Image and file I/O: linear float32 EXR (OpenEXR), sRGB PNG previews (colour-science), atomic writes.

Conventions (DESIGN.md): everything on disk and in tensors is linear scene-referred; sRGB encoding is
applied only at the edges (PNG previews, figures, metric inputs) through :func:`srgb_encode`.

Writes go to a temporary name beside the target and are renamed into place on success, so a crashed or
killed job never leaves a file that looks complete.
"""

from __future__ import annotations

import contextlib
import errno
import json
import os
import tempfile
from collections.abc import Iterator, Mapping, Sequence
from pathlib import Path

import numpy as np

from frng.confine import current_umask, temp_dir  # noqa: F401 -- staging folders' permissions live in frng.confine
from frng.hashing import file_sha256


class ImageError(ValueError):
    """An image file is missing, unreadable or has unexpected content. The message names the file."""


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike) -> Iterator[Path]:
    """Yield a temporary path in the target's folder; rename it to ``path`` if the block succeeds.

    The temporary name keeps the suffix (writers pick the format from it) and starts with ``.tmp-`` so a
    half-written file never matches the final name. The file gets the permissions an ordinary ``open`` would
    give (0666 minus the umask), not ``mkstemp``'s 0600.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".tmp-{path.stem}-", suffix=path.suffix, dir=path.parent)
    try:
        os.fchmod(fd, 0o666 & ~current_umask())
    finally:
        os.close(fd)
    tmp = Path(tmp)
    try:
        yield tmp
        # writers that replace the file (safetensors creates its own, 0600 whatever the umask) lose the mode
        os.chmod(tmp, 0o666 & ~current_umask())
        os.replace(tmp, path)
    except OSError as e:  # a full disk names the file it was writing (the bare errno names none)
        if e.errno == errno.ENOSPC and not str(e.strerror or "").startswith(f"{path}:"):
            raise write_failure(path, e) from e
        raise
    finally:
        if tmp.exists():
            tmp.unlink()


class CorruptFileError(ValueError):
    """An intermediate file (model, checkpoint, cache, prior) is truncated, corrupt, of another kind, or holds
    objects a safe load refuses. The message names the file and the cause."""


def write_failure(path: str | os.PathLike, e: BaseException) -> OSError:
    """An OSError naming ``path`` and the cause of a failed write; C++ writers (OpenEXR) report a full disk as
    'basic_ios::clear: iostream error', so the free space of the target's file system is checked."""
    path = Path(path)
    cause = f"{type(e).__name__}: {e}"
    errno_ = getattr(e, "errno", None)
    try:
        st = os.statvfs(path.parent)
        if st.f_bavail * st.f_frsize < (1 << 20) or errno_ == 28:
            return OSError(
                28,
                f"{path}: cannot write: no space left on device "
                f"({st.f_bavail * st.f_frsize} bytes free in {path.parent}; {cause})",
            )
    except OSError:
        pass
    return OSError(errno_ or 5, f"{path}: cannot write ({cause})")


_LAST_LOADED: tuple[str, str] | None = None


def last_loaded() -> tuple[str, str] | None:
    """(path, what) of the last file :func:`load_torch` read: the file a following ``load_state_dict`` error is
    about (``frng.cli.run_stage`` names it)."""
    return _LAST_LOADED


def check_model_file(state, path: str | os.PathLike, what: str, arch_bounds: Mapping | None = None) -> None:
    """A model file (``what`` ends with "model file"): a dict with a ``config`` dict and a ``state_dict`` of floating,
    finite tensors; else :class:`CorruptFileError` naming the file and the key (integer weights would load into the
    float model as values of 1e8; NaN weights render NaN)."""
    import torch

    if not isinstance(state, dict):
        raise CorruptFileError(f"{path}: not a {what} (it holds a {type(state).__name__}, not a dict)")
    for key in ("config", "state_dict"):
        if not isinstance(state.get(key), dict):
            got = "missing" if key not in state else f"a {type(state[key]).__name__}"
            raise CorruptFileError(f"{path}: {what}: key {key!r} is {got}, expected a dict")
    for k, v in state["state_dict"].items():
        if not isinstance(v, torch.Tensor):
            raise CorruptFileError(f"{path}: {what}: state_dict entry {k!r} is a {type(v).__name__}, not a tensor")
        if not v.is_floating_point():
            raise CorruptFileError(f"{path}: {what}: weight {k!r} has dtype {v.dtype}; weights are floating point")
        if not torch.isfinite(v).all():
            raise CorruptFileError(f"{path}: {what}: weight {k!r} has non-finite values (NaN or inf)")
    check_architecture(state, path, what, arch_bounds)


def check_architecture(state: dict, path: str | os.PathLike, what: str, bounds: Mapping | None = None) -> None:
    """A model file's architecture record (``config``; ``raster`` / ``shading`` where present) before a model is
    built from it: finite numbers, each within ``bounds`` (key name -> (minimum, maximum); the loaders pass
    :func:`frng.plan.sections.architecture_bounds`, the config schema's maxima), any other integer of ``config`` at
    most :data:`frng.confine.MAX_ARCH_SIZE`, integers not negative; else :class:`CorruptFileError` naming the file
    and the key (a crafted ``hidden: 300000`` would allocate 1 TB)."""
    from frng import confine

    try:
        for key in ("config", "raster", "shading"):
            if isinstance(state.get(key), dict):
                int_max = confine.MAX_ARCH_SIZE if key == "config" else None
                confine.check_record(
                    state[key], source=f"{path}: {what}", field=key, bounds=bounds or {}, int_max=int_max
                )
    except confine.UntrustedInputError as e:
        raise CorruptFileError(str(e)) from None


def load_torch(path: str | os.PathLike, what: str = "file", arch_bounds: Mapping | None = None):
    """``torch.load`` of a file frng wrote (a model, checkpoint or prior), safely: ``weights_only=True``, so a
    crafted pickle cannot run code (only tensors and plain Python data load). Errors name the file: a missing
    one is FileNotFoundError; a truncated, corrupt or foreign one (or one holding other objects) is
    :class:`CorruptFileError`; so is a model file (``what`` ending in "model file") that is not a dict with a
    ``config`` and floating, finite weights (:func:`check_model_file`)."""
    global _LAST_LOADED

    path = Path(path)
    state = _load_torch(path, what)
    _LAST_LOADED = (str(path), what)
    if what.endswith("model file"):
        check_model_file(state, path, what, arch_bounds)
    return state


def _load_torch(path: Path, what: str):
    import pickle

    import torch

    if not path.exists():
        raise FileNotFoundError(f"{path}: {what} does not exist")
    try:
        return torch.load(path, map_location="cpu", weights_only=True)
    except pickle.UnpicklingError as e:
        first = str(e).strip().splitlines()[0] if str(e).strip() else type(e).__name__
        if "weights only" in str(e).lower() or "unsupported" in str(e).lower():
            raise CorruptFileError(
                f"{path}: refusing to load this {what}: it holds objects other than tensors and "
                f"plain data, which only an unsafe load would run ({first[:300]})"
            ) from None
        raise CorruptFileError(
            f"{path}: cannot read {what}: truncated or corrupt ({first[:300]}); delete it and "
            f"rerun the rule that makes it"
        ) from None
    except Exception as e:  # noqa: BLE001 -- zip/stream errors (PytorchStreamReader failed ...), EOFError, ...
        first = str(e).strip().splitlines()[0] if str(e).strip() else ""
        raise CorruptFileError(
            f"{path}: cannot read {what}: truncated or corrupt ({type(e).__name__}: "
            f"{first[:300]}); delete it and rerun the rule that makes it"
        ) from None


def save_torch(obj, path: str | os.PathLike) -> None:
    """``torch.save`` through a temporary file renamed into place (a killed job leaves no partial file). The zip
    is written through a file object so that its records are named ``archive/`` rather than after the random
    temporary name: the same object gives the same bytes (and sha256)."""
    import torch

    with atomic_path(path) as tmp:
        try:
            with open(tmp, "wb") as f:
                torch.save(obj, f)
        except (OSError, RuntimeError) as e:
            raise write_failure(path, e) from e


def safetensors_bytes(tensors: Mapping, metadata: Mapping[str, str] | None = None) -> bytes:
    """A safetensors file's bytes with a canonical header: ``safetensors.torch.save`` writes the metadata dict in
    a random order per process (a Rust hash map), so the same tensors gave files with different sha256; here the
    header's keys are sorted (same JSON, same length, so the data offsets and padding stay valid)."""
    import struct

    from safetensors.torch import save

    raw = save({k: v.contiguous() for k, v in tensors.items()}, metadata=dict(metadata) if metadata else None)
    (n,) = struct.unpack("<Q", raw[:8])
    header = json.loads(raw[8 : 8 + n])
    if "__metadata__" in header:
        header["__metadata__"] = dict(sorted(header["__metadata__"].items()))
    canon = json.dumps(header, separators=(",", ":"), ensure_ascii=False).encode()
    if len(canon) > n:  # an escape spelled differently from the library's: keep its bytes (valid, unsorted)
        return raw
    return raw[:8] + canon + b" " * (n - len(canon)) + raw[8 + n :]


def save_safetensors(tensors: Mapping, path: str | os.PathLike, metadata: Mapping[str, str] | None = None) -> None:
    """Write :func:`safetensors_bytes` atomically (a killed job leaves no partial file); permissions follow the
    umask (safetensors' own writer makes 0600 files)."""
    with atomic_path(path) as tmp:
        try:
            tmp.write_bytes(safetensors_bytes(tensors, metadata))
        except Exception as e:  # noqa: BLE001 -- safetensors' errors name no file (a full disk: os error 28)
            raise write_failure(path, e) from e


def write_json(path: str | os.PathLike, obj) -> None:
    with atomic_path(path) as tmp:
        tmp.write_text(json.dumps(obj, indent=2, sort_keys=False) + "\n")


def read_json(path: str | os.PathLike) -> dict:
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"{path} does not exist")
    try:
        return json.loads(path.read_text())
    except json.JSONDecodeError as e:
        raise ValueError(f"{path}: invalid JSON ({e})") from e


# -- EXR ------------------------------------------------------------------------------------------


def read_exr_channels(path: str | os.PathLike) -> dict[str, np.ndarray]:
    """Read every channel of every part of an EXR as float32 (H, W) arrays, keyed by channel name.

    Multi-part files (Blender 5 multilayer) are flattened; names stay as stored (e.g. ``"ViewLayer.Depth.Z"``).
    """
    import OpenEXR

    path = Path(path)
    if not path.exists():
        raise ImageError(f"{path}: file does not exist")
    try:
        with OpenEXR.File(str(path), separate_channels=True) as f:
            out: dict[str, np.ndarray] = {}
            for part in f.parts:
                for name, ch in part.channels.items():
                    out[name] = np.asarray(ch.pixels, dtype=np.float32)
    except Exception as e:  # OpenEXR raises RuntimeError/ValueError with terse messages
        raise ImageError(f"{path}: cannot read EXR ({e})") from e
    if not out:
        raise ImageError(f"{path}: {_no_channels_cause(path)}")
    return out


def _no_channels_cause(path: Path) -> str:
    """Why OpenEXR returned no channels: its Python binding swallows a failed pixel read (a header declaring a
    huge data window: MemoryError) and returns the part without channels."""
    import OpenEXR

    try:
        with OpenEXR.File(str(path), header_only=True) as f:
            parts = []
            for part in f.parts:
                (x0, y0), (x1, y1) = (np.asarray(v) for v in part.header["dataWindow"])
                w, h = int(x1) - int(x0) + 1, int(y1) - int(y0) + 1
                names = [c.name for c in part.header.get("channels", [])]
                parts.append((w, h, names))
    except Exception:  # noqa: BLE001 -- fall back to the plain statement
        return "EXR has no channels"
    declared = [(w, h, n) for w, h, n in parts if n]
    if not declared:
        return "EXR has no channels"
    w, h, names = max(declared, key=lambda p: p[0] * p[1] * len(p[2]))
    gib = w * h * len(names) * 4 / 2**30
    return (
        f"cannot read the pixels of a {w}x{h} image with channels {names} ({gib:.1f} GiB as float32): the "
        f"header's data window is too large or corrupt ({path.stat().st_size} bytes on disk)"
    )


def read_exr(path: str | os.PathLike, channels: Sequence[str]) -> np.ndarray:
    """Read the named channels, stacked in order, as float32 (H, W, len(channels))."""
    data = read_exr_channels(path)
    missing = [c for c in channels if c not in data]
    if missing:
        raise ImageError(f"{path}: missing channel(s) {missing}; has {sorted(data)}")
    return np.stack([data[c] for c in channels], axis=-1)


def read_rgba(path: str | os.PathLike, require_alpha: bool = False) -> np.ndarray:
    """Read an RGBA (or RGB; alpha then 1) EXR as float32 (H, W, 4), linear, premultiplied as stored.

    ``require_alpha``: an RGB-only file is an :class:`ImageError` (where the alpha is the object's mask)."""
    data = read_exr_channels(path)
    if not all(c in data for c in "RGB"):
        raise ImageError(f"{path}: expected R, G, B channels; has {sorted(data)}")
    if require_alpha and "A" not in data:
        raise ImageError(f"{path}: no alpha channel (has {sorted(data)}); expected RGBA with the object's mask in A")
    a = data.get("A", np.ones_like(data["R"]))
    return np.stack([data["R"], data["G"], data["B"], a], axis=-1)


def write_exr(
    path: str | os.PathLike,
    image: np.ndarray | Mapping[str, np.ndarray],
    channels: Sequence[str] | None = None,
    half: bool = False,
) -> None:
    """Write a linear EXR atomically (ZIP compression).

    image: (H, W, C) array with ``channels`` naming each of the C channels (default R,G,B[,A]),
    or a mapping name -> (H, W) array.
    """
    import OpenEXR

    if isinstance(image, Mapping):
        planes = {k: np.asarray(v) for k, v in image.items()}
    else:
        image = np.asarray(image)
        if image.ndim == 2:
            image = image[..., None]
        if channels is None:
            channels = {1: ["Y"], 3: ["R", "G", "B"], 4: ["R", "G", "B", "A"]}.get(image.shape[-1])
            if channels is None:
                raise ValueError(f"{path}: name the {image.shape[-1]} channels explicitly")
        if len(channels) != image.shape[-1]:
            raise ValueError(f"{path}: {len(channels)} channel names for {image.shape[-1]} channels")
        planes = {name: image[..., i] for i, name in enumerate(channels)}
    dtype = np.float16 if half else np.float32
    planes = {k: np.ascontiguousarray(v, dtype=dtype) for k, v in planes.items()}
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    with atomic_path(path) as tmp:
        try:
            with OpenEXR.File(header, {k: OpenEXR.Channel(k, v) for k, v in planes.items()}) as f:
                f.write(str(tmp))
        except (OSError, RuntimeError) as e:  # a full disk: 'basic_ios::clear: iostream error'
            raise write_failure(path, e) from e


# -- colour / PNG ---------------------------------------------------------------------------------


def srgb_encode(linear: np.ndarray) -> np.ndarray:
    """Linear [0, 1] -> sRGB-encoded [0, 1] (IEC 61966-2-1 via colour-science); values are clipped first."""
    import colour

    return np.asarray(colour.cctf_encoding(np.clip(linear, 0.0, 1.0), function="sRGB"), dtype=np.float32)


def srgb_decode(encoded: np.ndarray) -> np.ndarray:
    import colour

    return np.asarray(colour.cctf_decoding(np.clip(encoded, 0.0, 1.0), function="sRGB"), dtype=np.float32)


def composite(rgba, background: Sequence[float] = (1.0, 1.0, 1.0)):
    """Premultiplied RGBA (..., 4) over a constant background -> RGB (..., 3); a numpy array or a torch tensor
    (differentiable, on the tensor's device and dtype)."""
    if isinstance(rgba, np.ndarray):
        bg = np.asarray(background, dtype=np.float32)
    else:
        import torch

        bg = torch.as_tensor(background, dtype=rgba.dtype, device=rgba.device)
    return rgba[..., :3] + (1.0 - rgba[..., 3:4]) * bg


def tonemap(linear_rgb: np.ndarray, exposure: float = 1.0) -> np.ndarray:
    """Linear HDR RGB -> display sRGB in [0, 1]: exposure scale, clip, sRGB encode (for previews/figures)."""
    return srgb_encode(linear_rgb * exposure)


TIFF_MAGIC = (b"II*\x00", b"MM\x00*")


def read_hdr(path: str | os.PathLike) -> np.ndarray:
    """A Radiance .hdr (RGBE) as float32 linear RGB (H, W, 3), with OpenCV (``IMREAD_ANYDEPTH``: imageio's default
    plugin for .hdr is OpenCV's 8-bit read once opencv-python is installed). A float TIFF named .hdr (what the
    benchmark writers wrote before :func:`write_hdr`) is read as TIFF. Errors propagate; callers name the file."""
    path = Path(path)
    with open(path, "rb") as f:
        head = f.read(4)
    if head in TIFF_MAGIC:
        import imageio.v3 as iio

        return np.asarray(iio.imread(path, plugin="tifffile"), dtype=np.float32)[..., :3]
    import cv2

    img = cv2.imread(str(path), cv2.IMREAD_ANYDEPTH | cv2.IMREAD_COLOR)
    if img is None:
        raise ValueError("OpenCV could not decode it")
    return np.ascontiguousarray(img[..., ::-1], dtype=np.float32)


def write_hdr(path: str | os.PathLike, image: np.ndarray) -> None:
    """A Radiance .hdr (RGBE, run-length encoded) of linear RGB (H, W, 3+), atomically, with OpenCV."""
    import cv2

    img = np.ascontiguousarray(np.asarray(image, dtype=np.float32)[..., 2::-1])
    with atomic_path(path) as tmp:
        if not cv2.imwrite(str(tmp), img):
            raise write_failure(Path(path), OSError(f"OpenCV could not write {path}"))


def write_png(path: str | os.PathLike, image: np.ndarray) -> None:
    """Write an already display-encoded float [0, 1] (H, W, 3|4) or uint8 image as PNG, atomically."""
    import imageio.v3 as iio

    img = np.asarray(image)
    if img.dtype != np.uint8:
        img = (np.clip(img, 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)
    with atomic_path(path) as tmp:
        iio.imwrite(tmp, img)


def read_png(path: str | os.PathLike) -> np.ndarray:
    """Read a PNG as float32 [0, 1] (H, W, C), values as stored (no decoding)."""
    import imageio.v3 as iio

    from frng.confine import UntrustedInputError, check_image_size

    path = Path(path)
    if not path.exists():
        raise ImageError(f"{path}: file does not exist")
    try:
        check_image_size(path)  # a PNG, of a bounded size: checked from its header before decoding
        img = iio.imread(path)
    except UntrustedInputError as e:
        raise ImageError(str(e)) from None
    except Exception as e:
        first = str(e).strip().splitlines()[0] if str(e).strip() else type(e).__name__
        raise ImageError(f"{path}: cannot read PNG ({first[:300]})") from e
    scale = 65535.0 if img.dtype == np.uint16 else 255.0
    return img.astype(np.float32) / scale


def write_file_index(
    paths: Sequence[str | os.PathLike], out: str | os.PathLike, log: str | os.PathLike | None = None, **fields
) -> Path:
    """Write ``out``: a JSON index ``{**fields, "files": [{"path", "bytes", "sha256"}, ...]}`` of files a later stage
    depends on as a whole (e.g. the training split's caches), atomically; a missing file raises FileNotFoundError
    naming it. ``log``: where to note what was indexed. :func:`check_file_index` verifies it."""
    entries = []
    for p in paths:
        if not os.path.exists(p):
            raise FileNotFoundError(f"{p}: cannot index a missing file")
        entries.append({"path": str(p), "bytes": os.path.getsize(p), "sha256": file_sha256(p)})
    write_json(out, {**fields, "files": entries})
    if log is not None:
        Path(log).parent.mkdir(parents=True, exist_ok=True)
        Path(log).write_text(f"indexed {len(entries)} files into {out}\n")
    return Path(out)


def check_file_index(index: str | os.PathLike, hashes: bool = True) -> int:
    """Verify the files a :func:`write_file_index` index records: each exists with the recorded size (and
    sha256, where recorded and ``hashes``). A mismatch is :class:`CorruptFileError` naming the file and the index
    (the file was truncated, corrupted or replaced since it was indexed). Returns the number of files checked.

    A file whose inode last changed (``st_ctime``, which writes, renames and ``cp -p`` all set and nothing can set
    back; and ``st_mtime``) strictly before the index was written is not hashed again: it is the file that was
    indexed (re-hashing a training split's caches took ~8 s of every training job); its size is still checked."""
    entries = read_json(index).get("files", [])
    indexed_ns = os.stat(index).st_mtime_ns
    for e in entries:
        p = Path(e["path"])
        if not p.exists():
            raise FileNotFoundError(f"{p}: listed in {index} but missing; rerun the rule that makes it")
        st = p.stat()
        if st.st_size != e.get("bytes", st.st_size):
            raise CorruptFileError(
                f"{p}: {st.st_size} bytes, but {index} recorded {e['bytes']} (truncated or replaced "
                f"since it was indexed); delete it and rerun the rule that makes it"
            )
        if hashes and e.get("sha256") and max(st.st_mtime_ns, st.st_ctime_ns) >= indexed_ns:
            digest = file_sha256(p)
            if digest != e["sha256"]:
                raise CorruptFileError(
                    f"{p}: sha256 {digest[:12]}, but {index} recorded "
                    f"{e['sha256'][:12]} (corrupted or replaced since it was indexed); delete it "
                    f"and rerun the rule that makes it"
                )
    return len(entries)
