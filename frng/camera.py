"""Camera maths -- the one place that owns it (OpenCV convention).

Conventions (DESIGN.md):
- Camera frame: x right, y down, z forward (the camera looks along +z).
- A camera is a 4x4 camera-to-world matrix ``c2w`` plus intrinsics ``(fx, fy, cx, cy)`` in pixels.
- Pixel ``(col, row)`` covers ``[col, col+1) x [row, row+1)``; its centre is ``(col + 0.5, row + 0.5)``.
  Image coordinates ``uv = (x, y)`` are continuous in that pixel space.
- World: Z up, objects normalised into the unit sphere at the origin.

Blender's camera frame is x right, y up, z backward; :func:`c2w_from_blender` converts it once.

Torch functions take and return tensors with leading batch dims ``...``; the small numpy helpers
(:func:`look_at`, :func:`c2w_from_blender`, :func:`intrinsics_from_fov`) serve metadata code.
"""

from __future__ import annotations

import math

import numpy as np

from frng.lazytorch import torch

# Blender camera frame (x right, y up, z back) -> OpenCV (x right, y down, z forward): flip y and z.
BLENDER_TO_OPENCV = np.diag([1.0, -1.0, -1.0, 1.0])


# -- numpy helpers (metadata, rigs) ---------------------------------------------------------------


def c2w_from_blender(matrix_world: np.ndarray) -> np.ndarray:
    """Blender camera ``matrix_world`` (4, 4) -> OpenCV camera-to-world (4, 4)."""
    return np.asarray(matrix_world, dtype=np.float64) @ BLENDER_TO_OPENCV


def c2w_to_blender(c2w: np.ndarray) -> np.ndarray:
    """OpenCV camera-to-world (4, 4) -> Blender camera ``matrix_world`` (4, 4)."""
    return np.asarray(c2w, dtype=np.float64) @ BLENDER_TO_OPENCV


def intrinsics_from_fov(fov_x_deg: float, width: int, height: int) -> np.ndarray:
    """Pinhole intrinsics ``(fx, fy, cx, cy)`` for a horizontal field of view, square pixels, centred."""
    fx = 0.5 * width / math.tan(math.radians(fov_x_deg) / 2.0)
    return np.array([fx, fx, width / 2.0, height / 2.0])


def look_at(eye, target=(0.0, 0.0, 0.0), up=(0.0, 0.0, 1.0)) -> np.ndarray:
    """OpenCV camera-to-world (4, 4) at ``eye`` looking at ``target`` with world ``up`` (Z) pointing up in the image."""
    eye = np.asarray(eye, dtype=np.float64)
    z = np.asarray(target, dtype=np.float64) - eye
    z /= np.linalg.norm(z)
    up = np.asarray(up, dtype=np.float64)
    if abs(np.dot(z, up)) > 0.999:  # looking straight up/down: pick another up
        up = np.array([0.0, 1.0, 0.0]) if abs(z[1]) < 0.9 else np.array([1.0, 0.0, 0.0])
    x = np.cross(z, up)  # right = forward x up (y is down)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    c2w = np.eye(4)
    c2w[:3, 0], c2w[:3, 1], c2w[:3, 2], c2w[:3, 3] = x, y, z, eye
    return c2w


def spherical_to_cartesian(azimuth_deg: float, elevation_deg: float, radius: float) -> np.ndarray:
    """Point on a sphere around the origin: azimuth from +X towards +Y, elevation from the XY plane."""
    az, el = math.radians(azimuth_deg), math.radians(elevation_deg)
    return radius * np.array([math.cos(el) * math.cos(az), math.cos(el) * math.sin(az), math.sin(el)])


# -- torch ----------------------------------------------------------------------------------------


def pixel_centers(height: int, width: int, device=None, dtype=None) -> torch.Tensor:
    """Pixel-centre coordinates ``uv`` (H, W, 2) = (col + 0.5, row + 0.5); dtype default float32."""
    dtype = torch.float32 if dtype is None else dtype
    ys = torch.arange(height, device=device, dtype=dtype) + 0.5
    xs = torch.arange(width, device=device, dtype=dtype) + 0.5
    yy, xx = torch.meshgrid(ys, xs, indexing="ij")
    return torch.stack([xx, yy], dim=-1)


def rays_at(c2w: torch.Tensor, intrinsics: torch.Tensor, uv: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """World-space rays through image positions (sub-pixel allowed).

    c2w: (V, 4, 4); intrinsics: (V, 4) as fx, fy, cx, cy; uv: (V, ..., 2) pixel coordinates.
    Returns origins (V, ..., 3) and unit directions (V, ..., 3).
    """
    V = c2w.shape[0]
    extra = uv.dim() - 2
    shape = (V,) + (1,) * extra
    fx, fy, cx, cy = (intrinsics[:, i].reshape(shape) for i in range(4))
    x = (uv[..., 0] - cx) / fx
    y = (uv[..., 1] - cy) / fy
    R = c2w[:, :3, :3].reshape((V,) + (1,) * extra + (3, 3))
    # d = R (x, y, 1), row by row in the order of the 3 x 3 product's sum (the same floats as ``R @ d_cam``)
    d = torch.stack([R[..., i, 0] * x + R[..., i, 1] * y + R[..., i, 2] for i in range(3)], dim=-1)
    d = d / d.norm(dim=-1, keepdim=True)
    o = c2w[:, :3, 3].reshape((V,) + (1,) * extra + (3,)).expand_as(d)
    return o, d


def pixel_rays(
    c2w: torch.Tensor, intrinsics: torch.Tensor, height: int, width: int
) -> tuple[torch.Tensor, torch.Tensor]:
    """Rays through every pixel centre: origins, directions (V, H, W, 3)."""
    uv = pixel_centers(height, width, device=c2w.device, dtype=c2w.dtype)
    return rays_at(c2w, intrinsics, uv.expand(c2w.shape[0], height, width, 2))


def plucker(origins: torch.Tensor, directions: torch.Tensor) -> torch.Tensor:
    """Pluecker ray coordinates (..., 6) = (d, o x d) for unit directions d (the backbone's pose input)."""
    return torch.cat([directions, torch.cross(origins, directions, dim=-1)], dim=-1)


def world_to_camera(points: torch.Tensor, c2w: torch.Tensor) -> torch.Tensor:
    """points (N, 3) or (V, N, 3) -> camera-frame points (V, N, 3)."""
    w2c = torch.linalg.inv(c2w)
    if points.dim() == 2:
        points = points.unsqueeze(0).expand(c2w.shape[0], -1, -1)
    return points @ w2c[:, :3, :3].transpose(1, 2) + w2c[:, None, :3, 3]


def project(points: torch.Tensor, c2w: torch.Tensor, intrinsics: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Project world points into each camera.

    points: (N, 3) or (V, N, 3); c2w: (V, 4, 4); intrinsics: (V, 4).
    Returns uv (V, N, 2) in pixel coordinates and depth (V, N) = camera-frame z (negative: behind).
    """
    p = world_to_camera(points, c2w)
    z = p[..., 2]
    zs = torch.where(z.abs() < 1e-9, torch.full_like(z, 1e-9), z)
    fx, fy, cx, cy = (intrinsics[:, i, None] for i in range(4))
    uv = torch.stack([fx * p[..., 0] / zs + cx, fy * p[..., 1] / zs + cy], dim=-1)
    return uv, z


def unproject(uv: torch.Tensor, depth: torch.Tensor, c2w: torch.Tensor, intrinsics: torch.Tensor) -> torch.Tensor:
    """Inverse of :func:`project`: uv (V, ..., 2) and z-depth (V, ...) -> world points (V, ..., 3)."""
    V = c2w.shape[0]
    extra = uv.dim() - 2
    shape = (V,) + (1,) * extra
    fx, fy, cx, cy = (intrinsics[:, i].reshape(shape) for i in range(4))
    p = torch.stack([(uv[..., 0] - cx) / fx * depth, (uv[..., 1] - cy) / fy * depth, depth], dim=-1)
    R = c2w[:, :3, :3].reshape((V,) + (1,) * extra + (3, 3))
    return (R @ p.unsqueeze(-1)).squeeze(-1) + c2w[:, :3, 3].reshape((V,) + (1,) * extra + (3,))
