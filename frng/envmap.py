"""Equirectangular environment maps: the direction <-> uv convention, I/O, rotation.

Convention (matches Blender's Environment Texture node with default mapping, world Z up; verified by
``tests/test_envmap_blender.py`` with a Cycles mirror sphere):

- ``u`` runs left -> right and ``v`` top -> bottom over [0, 1); pixel (col, row) has its centre at
  ``u = (col + 0.5) / W``, ``v = (row + 0.5) / H``.
- ``phi = pi * (1 - 2u)`` (azimuth from +X towards +Y), ``theta = pi * (0.5 - v)`` (elevation),
  ``direction = (cos(theta) cos(phi), cos(theta) sin(phi), sin(theta))``.
- Inverse: ``u = 0.5 - atan2(y, x) / (2 pi)  (mod 1)``, ``v = acos(z) / pi``.
- The image centre looks along +X, ``u = 0.25`` along +Y, the top row is +Z.

Maps are linear HDR float32 RGB with ``width == 2 * height``. ``E(direction)`` is the radiance arriving
*from* that direction.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import torch

from frng import io


class EnvMapError(ValueError):
    """An environment map is missing, unreadable or not a 2:1 equirect RGB image; names the file."""


def uv_to_dir(u: torch.Tensor, v: torch.Tensor) -> torch.Tensor:
    """Equirect (u, v) in [0, 1) -> unit world direction (..., 3)."""
    phi = math.pi * (1.0 - 2.0 * u)
    theta = math.pi * (0.5 - v)
    ct = torch.cos(theta)
    return torch.stack([ct * torch.cos(phi), ct * torch.sin(phi), torch.sin(theta)], dim=-1)


def dir_to_uv(d: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Unit world direction (..., 3) -> equirect (u, v), each (...), u in [0, 1), v in [0, 1]."""
    u = torch.remainder(0.5 - torch.atan2(d[..., 1], d[..., 0]) / (2.0 * math.pi), 1.0)
    v = torch.acos(d[..., 2].clamp(-1.0, 1.0)) / math.pi
    return u, v


def pixel_uv(height: int, width: int, device=None, dtype=torch.float32) -> tuple[torch.Tensor, torch.Tensor]:
    """(u, v) of every pixel centre, each (H, W)."""
    v = (torch.arange(height, device=device, dtype=dtype) + 0.5) / height
    u = (torch.arange(width, device=device, dtype=dtype) + 0.5) / width
    vv, uu = torch.meshgrid(v, u, indexing="ij")
    return uu, vv


def pixel_directions(height: int, width: int, device=None, dtype=torch.float32) -> torch.Tensor:
    """Unit direction of every pixel centre (H, W, 3)."""
    return uv_to_dir(*pixel_uv(height, width, device, dtype))


def pixel_solid_angles(height: int, width: int, device=None, dtype=torch.float64) -> torch.Tensor:
    """Exact solid angle of each pixel (H, W); sums to 4 pi."""
    edges = torch.linspace(0.0, math.pi, height + 1, device=device, dtype=dtype)  # polar angle edges
    band = (torch.cos(edges[:-1]) - torch.cos(edges[1:])) * (2.0 * math.pi / width)
    return band[:, None].expand(height, width)


def check_shape(image: np.ndarray, name: str = "environment map") -> None:
    if image.ndim != 3 or image.shape[-1] < 3:
        raise EnvMapError(f"{name}: expected an (H, W, 3) RGB image, got shape {image.shape}")
    h, w = image.shape[:2]
    if w != 2 * h:
        raise EnvMapError(f"{name}: equirect maps must be 2:1 (width = 2 x height), got {w}x{h}")


def read(path: str | Path) -> np.ndarray:
    """Read an equirect map (EXR, or Radiance HDR) as linear float32 (H, W, 3), negatives clamped to 0."""
    path = Path(path)
    if not path.exists():
        raise EnvMapError(f"{path}: environment map does not exist")
    try:
        if path.suffix.lower() == ".exr":
            img = io.read_exr(path, ["R", "G", "B"])
        elif path.suffix.lower() == ".hdr":
            import imageio.v3 as iio

            img = np.asarray(iio.imread(path), dtype=np.float32)[..., :3]
        else:
            raise EnvMapError(f"{path}: unsupported environment map format (use .exr or .hdr)")
    except io.ImageError as e:
        raise EnvMapError(str(e)) from e
    check_shape(img, str(path))
    if not np.all(np.isfinite(img)):
        raise EnvMapError(f"{path}: environment map contains NaN or Inf")
    return np.maximum(img, 0.0).astype(np.float32)


def write(path: str | Path, image: np.ndarray) -> None:
    """Write a linear float32 equirect map as EXR (atomically)."""
    check_shape(image, str(path))
    io.write_exr(path, np.asarray(image, dtype=np.float32)[..., :3])


def rotate_z(image: np.ndarray, angle_deg: float) -> np.ndarray:
    """Rotate a map about world Z by ``angle_deg`` (counter-clockwise seen from +Z).

    The rotated map satisfies ``E'(R d) = E(d)``: light from azimuth phi now arrives from phi + angle.
    With ``u = (1 - phi / pi) / 2`` this is a periodic shift of u by ``-angle / 360`` (linear interpolation).
    """
    h, w = image.shape[:2]
    shift = -angle_deg / 360.0 * w  # in pixels, sub-pixel allowed
    # E'(col) = E(col - shift): sample the source at col - shift
    src = (np.arange(w) - shift) % w
    i0 = np.floor(src).astype(int)
    t = (src - i0)[None, :, None].astype(np.float32)
    i1 = (i0 + 1) % w
    return ((1.0 - t) * image[:, i0] + t * image[:, i1]).astype(np.float32)


def resize(image: np.ndarray, width: int) -> np.ndarray:
    """Area-preserving resize of an equirect map to ``width`` x ``width/2`` (scikit-image, anti-aliased)."""
    from skimage.transform import resize as sk_resize

    out = sk_resize(image, (width // 2, width, image.shape[-1]), order=1, anti_aliasing=True, preserve_range=True)
    return np.maximum(out, 0.0).astype(np.float32)


def luminance(rgb: np.ndarray | torch.Tensor):
    """Rec. 709 luminance of linear RGB (..., 3)."""
    w = (0.2126, 0.7152, 0.0722)
    return rgb[..., 0] * w[0] + rgb[..., 1] * w[1] + rgb[..., 2] * w[2]
