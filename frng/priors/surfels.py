"""Pixel-footprint surfels: the shape a per-pixel Gaussian takes when it stands for its pixel's patch of surface.

A per-pixel Gaussian sits on its input pixel's ray at the surface (distance ``t``). What its pixel sees there is a
patch of the surface about ``t / fx`` wide across, and ``1 / |cos|`` times longer along the direction in which the
surface tilts away from the ray (``cos``: between the ray and the surface normal). A surfel covers exactly that: a
flat Gaussian in the surface plane, :data:`PIXEL_STD` pixels wide (the standard deviation of a one-pixel box) at
its distance across the tilt, ``1 / |cos|`` times that along it (at most :data:`MAX_STRETCH`), :data:`THICKNESS` of
its width thick. Seen from another view, neighbouring surfels then join up into a closed surface: a surface the
input view saw at a grazing angle covers its whole extent, not a row of dots with the background between them.

Why it matters (README "Surfels"): the backbone learns near-point Gaussians (standard deviation ~0.003 world units,
~0.08 px at 64 px), which the rasterizer's 0.3 px^2 low-pass turns into ~0.55 px blobs: enough to cover the input
views, not the target views that look at a surface the inputs saw obliquely (stripes of background through the
object; with 2 input views 16 % of the target foreground was left uncovered).

Normals come from the Gaussians themselves: finite differences of their means on the input pixel grid
(:func:`grid_normals`, :func:`frng.priors.multiview.depth_normals`), so no extra input is needed.

Shapes: N Gaussians; ``means``/``dirs``/``normals`` (N, 3); quaternions (w, x, y, z) as gsplat.
"""

from __future__ import annotations

import math

import torch

from frng import camera
from frng.gaussians import Gaussians
from frng.render.project import rotmat_to_quat

PIXEL_STD = 1.0 / math.sqrt(12.0)  # a surfel's width in pixels: the standard deviation of a one-pixel box
MAX_STRETCH = 4.0  # a surfel grows along the tilt by 1 / |cos| up to this factor
THICKNESS = 0.1  # its standard deviation along the normal, in units of its width


def grid_normals(means: torch.Tensor, keep: torch.Tensor, c2w: torch.Tensor) -> torch.Tensor:
    """World normals (V, H, W, 3) of per-pixel Gaussians: means (V*H*W, 3) on the input pixel grid of square views
    (view, row, col order), keep (V*H*W,) bool, c2w (V, 4, 4); from finite differences of the means between kept
    neighbours (:func:`frng.priors.multiview.depth_normals`), facing the input camera."""
    from frng.priors.multiview import depth_normals

    V = c2w.shape[0]
    pts = means.reshape(V, -1, 3)
    H = W = int(round(pts.shape[1] ** 0.5))
    assert H * W == pts.shape[1], f"per-pixel Gaussians of square views expected, got {pts.shape[1]} per view"
    assert keep.shape == (V * H * W,), (keep.shape, means.shape)
    n_cam = depth_normals(pts.reshape(V, H, W, 3).float(), c2w, keep.reshape(V, H, W).bool())
    return (c2w[:, None, None, :3, :3].float() @ n_cam.unsqueeze(-1)).squeeze(-1)


def surfel_shapes(normals: torch.Tensor, dirs: torch.Tensor, width: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Rotations and scales of surfels (see the module docstring).

    normals (N, 3) unit surface normals; dirs (N, 3) unit rays of the pixels that see them; width (N,) the
    footprint's standard deviation across the tilt, in world units. Returns quats (N, 4) (local x: along the tilt,
    local z: the normal) and scales (N, 3) = width * (stretch, 1, THICKNESS)."""
    N = normals.shape[0]
    assert normals.shape == (N, 3) and dirs.shape == (N, 3) and width.shape == (N,), (
        normals.shape,
        dirs.shape,
        width.shape,
    )
    cos = (normals * dirs).sum(-1)
    t1 = dirs - cos[:, None] * normals  # the ray's direction within the surface plane: the axis the tilt stretches
    # a ray along the normal has no such direction: any tangent will do
    other = torch.where(
        normals[:, 2:3].abs() < 0.9, normals.new_tensor([0.0, 0.0, 1.0]), normals.new_tensor([1.0, 0.0, 0.0])
    )
    t1 = torch.where(t1.norm(dim=-1, keepdim=True) > 1e-4, t1, torch.cross(normals, other, dim=-1))
    t1 = t1 / t1.norm(dim=-1, keepdim=True).clamp_min(1e-8)
    t2 = torch.cross(normals, t1, dim=-1)
    quats = rotmat_to_quat(torch.stack([t1, t2, normals], -1))  # columns: local x, y, z in the world
    stretch = 1.0 / cos.abs().clamp_min(1.0 / MAX_STRETCH)
    w = width[:, None]
    return quats, torch.cat([w * stretch[:, None], w, w * THICKNESS], -1)


def pixel_surfels(
    gauss: Gaussians, keep: torch.Tensor, c2w: torch.Tensor, intr: torch.Tensor, normals: torch.Tensor | None = None
) -> Gaussians:
    """Per-pixel Gaussians (N = V*H*W on the input pixel grid; keep (N,) bool: the foreground ones) turned into
    surfels on their own rays, normals from their means (:func:`grid_normals`). c2w (V, 4, 4), intr (V, 4). Means,
    opacities and features are kept; rotations and scales are replaced."""
    V = c2w.shape[0]
    N = len(gauss)
    H = W = int(round((N // V) ** 0.5))
    assert V * H * W == N and intr.shape == (V, 4), (N, c2w.shape, intr.shape)
    o, d = camera.pixel_rays(c2w.float(), intr.float(), H, W)
    o, d = o.reshape(-1, 3), d.reshape(-1, 3)
    t = (gauss.means.float() - o).norm(dim=-1)
    fx = intr[:, 0].float().repeat_interleave(H * W)
    normals = grid_normals(gauss.means, keep, c2w).reshape(-1, 3) if normals is None else normals.reshape(-1, 3)
    quats, scales = surfel_shapes(normals, d, PIXEL_STD * t / fx)
    return Gaussians(gauss.means, quats, scales, gauss.opacities, gauss.features)


__all__ = ["MAX_STRETCH", "PIXEL_STD", "THICKNESS", "grid_normals", "pixel_surfels", "surfel_shapes"]
