"""Synthetic Gaussian scenes for benchmarks and tests (no data needed)."""

from __future__ import annotations

import numpy as np
import torch

from frng import camera


def paper_rig(views: int = 6, distance: float = 2.6) -> np.ndarray:
    """The paper's input rig as OpenCV c2w (V, 4, 4): front/back/left/right at 0 deg elevation and two views at
    45 deg elevation 180 deg apart; views beyond 6 go round at 20 deg elevation."""
    poses = [(0, 0), (90, 0), (180, 0), (270, 0), (45, 45), (225, 45)]
    poses += [(30 + 360 * i / max(views - 6, 1), 20) for i in range(max(views - 6, 0))]
    return np.stack([camera.look_at(camera.spherical_to_cartesian(a, e, distance)) for a, e in poses[:views]])


def rig_rays(size: int, views: int = 6, fov_deg: float = 50.0, distance: float = 2.6, dtype=torch.float32):
    """The paper rig's cameras (:func:`paper_rig`) at ``size`` x ``size`` pixels and their pixel rays: c2w (V, 4, 4),
    intrinsics (V, 4), origins and unit directions (V, size, size, 3) each."""
    c2w = torch.tensor(paper_rig(views, distance), dtype=dtype)
    K = torch.tensor(camera.intrinsics_from_fov(fov_deg, size, size), dtype=dtype).expand(views, 4).contiguous()
    o, d = camera.pixel_rays(c2w, K, size, size)
    return c2w, K, o, d


def pixel_aligned_scene(
    size: int,
    views: int = 6,
    channels: int = 32,
    fov_deg: float = 50.0,
    distance: float = 2.6,
    radius: float = 0.8,
    sigma_px: float = 1.0,
    seed: int = 0,
    dtype=torch.float32,
):
    """One Gaussian per input pixel, as an LRM predicts them: on a sphere of ``radius`` where the pixel's ray
    hits it (opacity 0.6-1), else at the ray's closest approach to the origin (opacity 0-0.2); flattened
    (1 : 1 : 0.3) with random orientation, and a 1-sigma size of ``sigma_px`` pixels in their own view
    (3-sigma footprint ~3 px).

    Returns a dict with means (N, 3), quats (N, 4), scales (N, 3), opacities (N,), features (N, C), c2w (V, 4, 4),
    intrinsics (V, 4) for N = views * size^2.
    """
    g = torch.Generator().manual_seed(seed)
    c2w, K, o, d = rig_rays(size, views, fov_deg, distance, dtype)
    o, d = o.reshape(-1, 3), d.reshape(-1, 3)
    b = (o * d).sum(-1)
    disc = b * b - ((o * o).sum(-1) - radius**2)
    hit = disc > 0
    t = torch.where(hit, -b - torch.sqrt(disc.clamp(min=0)), -b)
    means = o + t[:, None] * d
    n = means.shape[0]
    s = sigma_px * t / K[0, 0]
    scales = torch.stack([s, s, 0.3 * s], -1)
    quats = torch.randn(n, 4, generator=g, dtype=dtype)
    u = torch.rand(n, generator=g, dtype=dtype)
    opacities = torch.where(hit, 0.6 + 0.4 * u, 0.2 * u)
    features = torch.randn(n, channels, generator=g, dtype=dtype)
    return dict(means=means, quats=quats, scales=scales, opacities=opacities, features=features, c2w=c2w, intrinsics=K)
