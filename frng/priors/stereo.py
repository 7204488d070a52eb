"""Multi-view stereo inside the visual hull: semi-global matching (SGM) of the input views' colours, for the surface
behind the hull where the hull is wrong (a thin slab seen obliquely is a diamond to six views' silhouettes; a bowl's
opening is filled).

Per input view ``v`` the labels are ``labels`` fronto-parallel planes (camera z) evenly over the bounding sphere,
``camera distance +- radius``; a pixel's label k is the point of its ray at that plane. The data cost of (pixel, k)
is the mean of the best two other views' 3x3 box-filtered L1 difference of gamma-2.2 colours (unpremultiplied) at
the point's projection (a view whose mask is off there counts 1), plus:

- ``BIG`` outside the soft visual hull (occupancy below 0.5; a ray thinner than a pixel somewhere, whose occupancy
  never reaches 0.5, below half its peak: :func:`frng.priors.multiview.hull_distance`'s ``thin`` rule) and beyond
  the middle of the ray's hull segment (the visible surface lies in its front half; without this the opposite view
  matches the back of a uniform object);
- ``prior`` x (distance behind the pixel's hull entry): where the colours say nothing (uniform surfaces), the hull.

SGM (Hirschmueller 2008) sums the cost along 8 image directions with penalties ``p1`` for a one-label step and
``p2`` for any jump; the label of least summed cost, refined by a parabola through its neighbours, is the pixel's
plane. Background pixels (alpha < 0.5) carry no cost and keep the hull's far value.

Measured (issue 55; 96 px, 6 views, scratch on 20 training objects and the 21 test objects of the default tier,
depth error against the G-buffer along the input rays): the hull's mean absolute error 0.077 -> 0.068 (training
objects) and 0.059 -> 0.052 (test objects), pixels more than 4 px off 20 % -> 16 % and 17 % -> 13 %; the thin book
0.226 -> 0.198 (still mostly the hull's diamond: its cover is nearly uniform). Without the prior the textured slabs
come out (the book 0.11) but uniform objects sink (0.03 -> 0.17): the colours at 96 px cannot tell them apart.
F-RNG trained and relit on it (``frng train`` / ``frng bench heldout --geometry stereo``), paired against the
pipeline's model on the backbone's geometry: +0.07 [-0.05, +0.17] dB, LPIPS -0.0010 [-0.0034, +0.0020], the LIBERO
objects' LPIPS +0.0014: a diagnostic, not the pipeline's geometry (docs/priors.md).

Shapes: images (V, H, W, 3) linear premultiplied, alpha (V, H, W, 1), c2w (V, 4, 4) OpenCV, intr (V, 4);
distances along unit rays. Cost: V^2 H W K bilinear reads (6 views, 96 px, 96 labels: 32M; ~2 s an object on one
core with the SGM passes).
"""

from __future__ import annotations

import torch
import torch.nn.functional as F

from frng import camera
from frng.priors.backbone import ray_distance_target
from frng.priors.multiview import rays_occupancy, sample_image

BIG = 4.0  # cost of a label outside the hull's front half
DIRECTIONS = ((0, 1), (0, -1), (1, 0), (-1, 0), (1, 1), (1, -1), (-1, 1), (-1, -1))


def _step(prev: torch.Tensor, p1: float, p2: float) -> torch.Tensor:
    """SGM's recurrence term (..., K): min(L, L(k+-1) + p1, min L + p2) - min L of the previous pixel's costs."""
    m = prev.min(-1, keepdim=True).values
    up = F.pad(prev[..., 1:], (0, 1), value=1e9)
    dn = F.pad(prev[..., :-1], (1, 0), value=1e9)
    return torch.minimum(torch.minimum(prev, torch.minimum(up, dn) + p1), m + p2) - m


def aggregate(cost: torch.Tensor, p1: float, p2: float) -> torch.Tensor:
    """SGM: the cost (V, H, W, K) summed along the 8 directions of :data:`DIRECTIONS` (Hirschmueller's recurrence).
    Returns (V, H, W, K)."""
    assert cost.dim() == 4, cost.shape
    V, H, W, K = cost.shape
    total = torch.zeros_like(cost)
    for dy, dx in DIRECTIONS:
        L = cost.clone()
        if dy == 0:  # along rows
            xs = range(1, W) if dx > 0 else range(W - 2, -1, -1)
            for x in xs:
                L[:, :, x] += _step(L[:, :, x - dx], p1, p2)
        else:  # down / up the columns, diagonals: the previous row shifted by dx
            ys = range(1, H) if dy > 0 else range(H - 2, -1, -1)
            for y in ys:
                prev = L[:, y - dy]
                if dx > 0:
                    prev = torch.cat([prev[:, :1], prev[:, :-1]], 1)
                elif dx < 0:
                    prev = torch.cat([prev[:, 1:], prev[:, -1:]], 1)
                L[:, y] += _step(prev, p1, p2)
        total += L
    return total


def data_cost(
    rgb: torch.Tensor,
    alpha: torch.Tensor,
    c2w: torch.Tensor,
    intr: torch.Tensor,
    hull: torch.Tensor,
    planes: torch.Tensor,
    prior: float,
) -> torch.Tensor:
    """Matching cost (V, H, W, K) of every input pixel at the K planes ``planes`` (V, K) (camera z) of its view; see
    the module docstring. hull (V, H, W) the pixels' hull entry distances."""
    V, H, W, _ = rgb.shape
    K = planes.shape[1]
    col = (rgb / alpha.clamp_min(1e-3)).clamp(0, 1) ** (1 / 2.2)
    o, d = camera.pixel_rays(c2w, intr, H, W)
    dist = ray_distance_target(planes[:, None, None, :].expand(V, H, W, K), c2w, intr)  # the planes along the rays
    cost = torch.zeros(V, H, W, K)
    for v in range(V):
        fg = alpha[v, ..., 0] >= 0.5
        if not bool(fg.any()):
            continue
        of, df = o[v][fg], d[v][fg]
        t = dist[v][fg].contiguous()  # (R, K)
        R = t.shape[0]
        occ = rays_occupancy(alpha, of, df, t, c2w, intr)
        peak = occ.max(-1, keepdim=True).values.clamp_min(1e-6)
        inside = (occ >= 0.5) | ((peak < 0.5) & (occ >= 0.5 * peak))
        k = torch.arange(K)[None].expand(R, K)
        first = torch.where(inside, k, K).min(-1).values
        last = torch.where(inside, k, -1).max(-1).values
        inside &= k <= ((first + last) // 2 + 2)[:, None]  # the front half of the ray's hull segment
        pts = (of[:, None] + df[:, None] * t[..., None]).reshape(-1, 3)
        uv, z = camera.project(pts, c2w, intr)
        src = sample_image(torch.cat([col, alpha], -1), uv)  # (V, R*K, 4)
        ref = col[v][fg]
        diffs = []
        for u in range(V):
            if u == v:
                continue
            s = src[u].reshape(R, K, 4)
            seen = (s[..., 3] > 0.5) & (z[u].reshape(R, K) > 0)
            diff = torch.where(seen, (s[..., :3] - ref[:, None]).abs().mean(-1), torch.ones(R, K))
            img = torch.ones(H, W, K)
            img[fg] = diff
            img = F.avg_pool2d(img.permute(2, 0, 1)[None], 3, 1, 1, count_include_pad=False)[0].permute(1, 2, 0)
            diffs.append(img[fg])
        best2 = torch.stack(diffs).topk(min(2, len(diffs)), dim=0, largest=False).values.mean(0)
        behind = (t - hull[v][fg][:, None]).clamp_min(0)
        cost[v][fg] = best2 + prior * behind + BIG * (~inside).float()
    return cost


@torch.no_grad()
def stereo_distance(
    rgb: torch.Tensor,
    alpha: torch.Tensor,
    c2w: torch.Tensor,
    intr: torch.Tensor,
    hull: torch.Tensor,
    labels: int = 96,
    radius: float = 1.05,
    p1: float = 0.03,
    p2: float = 0.15,
    prior: float = 1.0,
) -> torch.Tensor:
    """Each input pixel's surface distance along its unit ray by SGM inside the visual hull (module docstring).

    rgb (V, H, W, 3) linear premultiplied; alpha (V, H, W, 1); c2w (V, 4, 4); intr (V, 4); hull (V, H, W) the
    pixels' hull distances (:func:`frng.priors.multiview.geometry_cues`' ``distance``). Returns (V, H, W): the
    stereo distance on foreground pixels (alpha >= 0.5), ``hull`` elsewhere."""
    V, H, W, _ = rgb.shape
    assert alpha.shape == (V, H, W, 1) and hull.shape == (V, H, W), (alpha.shape, hull.shape)
    assert c2w.shape == (V, 4, 4) and intr.shape == (V, 4), (c2w.shape, intr.shape)
    rgb, alpha, c2w, intr, hull = (x.float().cpu() for x in (rgb, alpha, c2w, intr, hull))
    step = 2 * radius / labels
    centre = c2w[:, :3, 3].norm(dim=-1)  # the camera's distance to the origin (the rig looks at it)
    planes = centre[:, None] - radius + (torch.arange(labels) + 0.5)[None] * step  # (V, K) camera z
    cost = data_cost(rgb, alpha, c2w, intr, hull, planes, prior)
    S = aggregate(cost, p1, p2)
    k = S.argmin(-1).clamp(1, labels - 2)
    s0, s1, s2 = (S.gather(-1, (k + j)[..., None])[..., 0] for j in (-1, 0, 1))
    off = ((s0 - s2) / (2 * (s0 - 2 * s1 + s2)).clamp_min(1e-9)).clamp(-0.5, 0.5)
    z = planes.gather(1, k.reshape(V, -1)).reshape(V, H, W) + off * step
    return torch.where(alpha[..., 0] >= 0.5, ray_distance_target(z[..., None], c2w, intr)[..., 0], hull)


__all__ = ["aggregate", "data_cost", "stereo_distance"]
