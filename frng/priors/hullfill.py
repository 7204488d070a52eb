"""Hull fill: Gaussians on the surface that no input view saw, so a target view there sees a surface, not the
background.

With few input views part of an object is seen by none of them: with the rig's two level views, its top and its
bottom. The per-pixel Gaussians (and the far-side copies of :func:`frng.priors.multiview.back_gaussians`) leave
those regions open, and a target view from above looks through the object at the white background. The object
still has to fill its silhouettes, so the surface there lies on or inside the visual hull.

The fill works on a voxel grid over the bounding sphere:

1. **Carved hull.** A voxel is solid when every input view sees it inside the object's mask and none sees it in
   front of the surface its per-pixel Gaussians reconstructed there (depth carving: the space between a camera and
   the surface it sees is empty).
2. **Unseen surface.** Solid voxels with an empty one among their 26 neighbours are the carved hull's surface. Those
   within ``tol`` of some view's reconstructed depth are surface the views saw (their Gaussians are already there);
   the others are unseen. Every unseen voxel lies behind the reconstructed surface in every view, so a fill never
   covers what an input view saw.
3. **Open.** An unseen voxel is filled only when the way from it to the object's centre crosses no voxel that
   Gaussians cover (their discs adding up to :data:`COVERED` of a voxel face): where front Gaussians or far-side
   copies lie inward of the hull (the hull of few views is loose: two level views cut a box around a ball), they
   are already the surface there, and a fill outside it would swell the object.
4. **Fill.** One flat Gaussian per open voxel at its centre, in the plane of the hull's normal (the gradient of the
   smoothed solid grid), a voxel wide (:data:`FILL_STD` of the spacing, so neighbours overlap), with the opacity of
   and the colour (``src``) of the nearest foreground Gaussian. Its ``dirs`` is the unit vector across whose normal
   plane the source's normal mirrors onto the hull normal (``n - 2 (n . d) d = h`` for ``d = (n - h) / |n - h|``),
   so the payload's normal channels face out of the hull as the far-side copies' do (:func:`mirror_normals`).

Shapes: alpha (V, H, W, 1); c2w (V, 4, 4); intr (V, 4); N = V*H*W per-pixel Gaussians (N, 3) means; keep (N,).
"""

from __future__ import annotations

import torch
import torch.nn.functional as F

from frng import camera
from frng.priors.multiview import sample_image
from frng.priors.surfels import grid_normals, surfel_shapes

GRID = 48  # voxels along each axis of the grid over the bounding sphere
FILL_STD = 0.6  # a fill's standard deviation across the surface, in voxel spacings (neighbours overlap)
COVERED = 0.5  # a voxel whose Gaussians' discs (2 pi s1 s2 opacity) add up to this share of a voxel face is surface
TOL_VOXELS = 1.5  # how near a view's reconstructed depth a voxel counts as seen, in voxel spacings


def _voxel_index(pts: torch.Tensor, radius: float, res: int) -> torch.Tensor:
    """Flat voxel index (P,) of points (P, 3) in the res^3 grid over [-radius, radius]^3 (clamped to the grid)."""
    ijk = ((pts + radius) / (2.0 * radius) * res).floor().long().clamp(0, res - 1)
    return (ijk[:, 0] * res + ijk[:, 1]) * res + ijk[:, 2]


def hull_fill_gaussians(
    means: torch.Tensor,
    scales: torch.Tensor,
    opacities: torch.Tensor,
    keep: torch.Tensor,
    alpha: torch.Tensor,
    c2w: torch.Tensor,
    intr: torch.Tensor,
    extra: dict | None = None,
    res: int = GRID,
    radius: float = 1.05,
) -> dict[str, torch.Tensor]:
    """Fill Gaussians on the unseen surface of the depth-carved visual hull (see the module docstring).

    means (N, 3), scales (N, 3), opacities (N,), keep (N,) bool: the N = V*H*W per-pixel Gaussians and which are
    foreground; alpha (V, H, W, 1) input masks; c2w (V, 4, 4); intr (V, 4); extra: other Gaussians already on the
    surface (the far-side copies: ``means`` (E, 3), ``scales`` (E, 3), ``opacities`` (E,)), which count as
    covering it. Returns the dict of :func:`frng.priors.multiview.back_gaussians`: ``means`` (M, 3), ``quats``
    (M, 4), ``scales`` (M, 3), ``opacities`` (M,), ``src`` (M,) int64 the nearest foreground pixel's index in N,
    ``dirs`` (M, 3) the mirror direction that turns the source's normal into the fill's (zero where they agree)."""
    V, H, W, _ = alpha.shape
    N = V * H * W
    assert means.shape == (N, 3) and scales.shape == (N, 3), (means.shape, scales.shape, alpha.shape)
    assert opacities.shape == (N,) and keep.shape == (N,), (opacities.shape, keep.shape)
    assert c2w.shape == (V, 4, 4) and intr.shape == (V, 4), (c2w.shape, intr.shape)
    c2w, intr, means, keep = c2w.float(), intr.float(), means.float(), keep.bool()
    h = 2.0 * radius / res
    ax = (torch.arange(res, device=means.device, dtype=torch.float32) + 0.5) * h - radius
    grid = torch.stack(torch.meshgrid(ax, ax, ax, indexing="ij"), -1).reshape(-1, 3)  # (P, 3) voxel centres
    if not keep.any():
        return _fills(grid[:0], grid[:0], keep.nonzero()[:, 0], means, opacities, keep, c2w, h)
    solid, seen = _carved_hull(grid, means, keep, alpha, c2w, intr, TOL_VOXELS * h, radius)
    cand = (_surface(solid, res) & ~seen).nonzero()[:, 0]
    gauss = [(means[keep], scales[keep].float(), opacities[keep].float())]
    if extra is not None:
        gauss.append((extra["means"].float(), extra["scales"].float(), extra["opacities"].float()))
    centre = means[keep].mean(0)
    if len(cand):
        cand = cand[~_blocked(grid[cand], centre, _covered(gauss, res, radius), res, radius)]
    normals = _hull_normals(solid, cand, grid[cand] - centre, res)
    return _fills(grid[cand], normals, keep.nonzero()[:, 0], means, opacities, keep, c2w, h)


def _fills(p, normals, fg_idx, means, opacities, keep, c2w, h: float) -> dict[str, torch.Tensor]:
    """The fill Gaussians at points p (M, 3) with unit normals (M, 3): colour, opacity and normal source the
    nearest foreground Gaussian (fg_idx (F,) its indices in N); see :func:`hull_fill_gaussians` for the keys."""
    src = fg_idx[:0]
    if len(p):
        src = torch.cat([fg_idx[torch.cdist(q, means[fg_idx]).argmin(-1)] for q in p.split(2048)])
    src_n = grid_normals(means, keep, c2w).reshape(-1, 3)[src]
    diff = src_n - normals
    dirs = torch.where(diff.norm(dim=-1, keepdim=True) > 1e-3, F.normalize(diff, dim=-1), torch.zeros_like(diff))
    quats, scales = surfel_shapes(normals, normals, torch.full((len(p),), FILL_STD * h, device=p.device))
    return {
        "means": p,
        "quats": quats,
        "scales": scales,
        "opacities": opacities.float()[src],
        "src": src,
        "dirs": dirs,
    }


def _carved_hull(grid, means, keep, alpha, c2w, intr, tol: float, radius: float):
    """solid (P,) bool: voxel centres grid (P, 3) in the bounding sphere, inside every view's mask and in no view in
    front of its reconstructed depth (the distance of the pixel's Gaussian) by more than tol; seen (P,) bool: within
    tol of some view's reconstructed depth."""
    V, H, W, _ = alpha.shape
    uv, z = camera.project(grid, c2w, intr)  # (V, P, 2), (V, P)
    dist = (grid[None] - c2w[:, None, :3, 3]).norm(dim=-1)  # (V, P) distance to each camera
    in_img = (z > 0) & (uv[..., 0] >= 0) & (uv[..., 0] <= W) & (uv[..., 1] >= 0) & (uv[..., 1] <= H)
    in_mask = (sample_image(alpha.float(), uv)[..., 0] >= 0.5) & in_img  # (V, P)
    depth = (means.reshape(V, H, W, 3) - c2w[:, None, None, :3, 3]).norm(dim=-1)
    depth = torch.where(keep.reshape(V, H, W), depth, torch.full_like(depth, float("inf")))
    d_px = sample_image(depth[..., None], uv, padding="border", mode="nearest")[..., 0]  # (V, P)
    carved = (dist < d_px - tol) & torch.isfinite(d_px)
    solid = (grid.norm(dim=-1) <= radius) & in_mask.all(0) & ~carved.any(0)
    return solid, ((dist - d_px).abs() <= tol).any(0)


def _surface(solid: torch.Tensor, res: int) -> torch.Tensor:
    """Solid voxels (P,) with an empty one among their 26 neighbours (outside the grid counts as empty)."""
    s3 = solid.reshape(1, 1, res, res, res).float()
    empty_nb = F.max_pool3d(1.0 - F.pad(s3, (1, 1, 1, 1, 1, 1), value=0.0), 3, stride=1)
    return solid & (empty_nb.reshape(-1) > 0)


def _covered(gauss, res: int, radius: float) -> torch.Tensor:
    """(P,) bool: voxels whose Gaussians' discs (2 pi s1 s2 opacity of the two largest scales) add up to
    :data:`COVERED` of a voxel face. gauss: (means (G, 3), scales (G, 3), opacities (G,)) groups."""
    h = 2.0 * radius / res
    cover = torch.zeros(res**3, device=gauss[0][0].device)
    for m, sc, op in gauss:
        s2 = sc.sort(-1, descending=True).values[:, :2]
        cover.index_add_(0, _voxel_index(m, radius, res), 2.0 * torch.pi * s2[:, 0] * s2[:, 1] * op / h**2)
    return cover >= COVERED


def _blocked(p: torch.Tensor, centre: torch.Tensor, covered: torch.Tensor, res: int, radius: float) -> torch.Tensor:
    """(M,) bool: the segment from each point p (M, 3) to centre (3,) passes a covered voxel (sampled every half
    voxel, the point's own position excluded)."""
    h = 2.0 * radius / res
    steps = max(2, int(torch.ceil((p - centre).norm(dim=-1).max() / (0.5 * h)).item()))
    s = torch.linspace(0.0, 1.0, steps, device=p.device)[1:]
    path = p[:, None] + (centre - p)[:, None] * s[None, :, None]  # (M, S, 3)
    return covered[_voxel_index(path.reshape(-1, 3), radius, res)].reshape(len(p), -1).any(-1)


def _hull_normals(solid: torch.Tensor, idx: torch.Tensor, outward: torch.Tensor, res: int) -> torch.Tensor:
    """Unit outward normals (M, 3) of the solid grid at voxels idx (M,): minus the gradient of the solid smoothed
    over 5^3 voxels; ``outward`` (M, 3) (from the object's centre) where that gradient vanishes."""
    s3 = solid.reshape(1, 1, res, res, res).float()
    sm = F.avg_pool3d(F.pad(s3, (2, 2, 2, 2, 2, 2)), 5, stride=1)[0, 0]
    g = -torch.stack(torch.gradient(sm), -1).reshape(-1, 3)[idx]
    return F.normalize(torch.where(g.norm(dim=-1, keepdim=True) > 1e-6, g, outward), dim=-1)


__all__ = ["COVERED", "FILL_STD", "GRID", "TOL_VOXELS", "hull_fill_gaussians"]
