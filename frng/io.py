"""Image and file I/O: linear float32 EXR (OpenEXR), sRGB PNG previews (colour-science), atomic writes.

Conventions (DESIGN.md): everything on disk and in tensors is linear scene-referred; sRGB encoding is
applied only at the edges (PNG previews, figures, metric inputs) through :func:`srgb_encode`.

Writes go to a temporary name beside the target and are renamed into place on success, so a crashed or
killed job never leaves a file that looks complete.
"""

from __future__ import annotations

import contextlib
import json
import os
import tempfile
from pathlib import Path
from typing import Iterator, Mapping, Sequence

import numpy as np


class ImageError(ValueError):
    """An image file is missing, unreadable or has unexpected content. The message names the file."""


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
        os.replace(tmp, path)
    finally:
        if tmp.exists():
            tmp.unlink()


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
        raise ImageError(f"{path}: EXR has no channels")
    return out


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
        raise ImageError(f"{path}: no alpha channel (has {sorted(data)}); expected RGBA with the object's mask "
                         f"in A")
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
        with OpenEXR.File(header, {k: OpenEXR.Channel(k, v) for k, v in planes.items()}) as f:
            f.write(str(tmp))


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

    path = Path(path)
    if not path.exists():
        raise ImageError(f"{path}: file does not exist")
    try:
        img = iio.imread(path)
    except Exception as e:
        raise ImageError(f"{path}: cannot read PNG ({e})") from e
    scale = 65535.0 if img.dtype == np.uint16 else 255.0
    return img.astype(np.float32) / scale


def write_file_index(paths: Sequence[str | os.PathLike], out: str | os.PathLike, log: str | os.PathLike | None = None,
                     **fields) -> Path:
    """Write ``out``: a JSON index ``{**fields, "files": [{"path", "bytes"}, ...]}`` of files a later stage depends on
    as a whole (e.g. the training split's caches), atomically; a missing file raises FileNotFoundError naming it.
    ``log``: where to note what was indexed."""
    entries = []
    for p in paths:
        if not os.path.exists(p):
            raise FileNotFoundError(f"{p}: cannot index a missing file")
        entries.append({"path": str(p), "bytes": os.path.getsize(p)})
    write_json(out, {**fields, "files": entries})
    if log is not None:
        Path(log).parent.mkdir(parents=True, exist_ok=True)
        Path(log).write_text(f"indexed {len(entries)} files into {out}\n")
    return Path(out)
