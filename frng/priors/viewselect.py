"""Frontal view selection: of the per-pixel Gaussians that several input views put on the same patch of surface,
keep the ones of the view that sees it most squarely.

Every input view puts one Gaussian on the surface behind each of its foreground pixels, so a surface that k views
see carries k overlapping layers of them, each with its own view's colour (shading and highlights differ between
views) and its own depth error. Rendered from a new view, whichever layer lies in front wins pixel by pixel: the
more views, the more layers and the more of that noise (README "Why 10 views score below 6": the 6 -> 10 view loss
sits where the input views look from, on well-seen surfaces). A view that sees the surface obliquely adds least: its
pixels' surfels are stretched by 1 / |cos| (:mod:`frng.priors.surfels`) and its colour is the least reliable.

A Gaussian is *dominated* when another input view sees the same point of surface more squarely: projected into
that view it lands on a foreground pixel whose own Gaussian lies at the same depth (within ``tol_px`` of that
pixel's footprint along its ray) and whose |cos| between ray and surface normal exceeds the Gaussian's own by
``margin``. Dominated Gaussians are not rendered; a point no other view covers keeps its Gaussian, so no hole opens
where only one view saw the surface, and a chain of dominations ends at the most frontal view, which keeps its layer.

The defaults (:data:`TOL_PX`, :data:`MARGIN`) were chosen on a validation set of 25 TRAINING objects (every 5th of
the default tier's training split, cached with 6 and 10 input views; F-RNG full model, aligned PSNR): the best mean
of the 6- and 10-view scores over tol 0.5 / 1 / 2 / 4 px x margin 0.1 / 0.3 / 0.5 (README "Priors", Frontal view
selection; the region around the choice is a plateau: margin 0 / 0.05 within 0.03 dB). A looser depth match (2-4
px) dropped Gaussians of nearby but different surfaces and lost up to 1.2 dB at 6 views.

Shapes: V views of H x W pixels, N = V*H*W per-pixel Gaussians in (view, row, col) order.
"""

from __future__ import annotations

import torch

from frng import camera

TOL_PX = 0.5  # same point of surface: depths within half a pixel footprint (along the other view's ray)
MARGIN = 0.1  # the other view must see it more squarely by this much |cos|


def dominated(
    means: torch.Tensor,
    normals: torch.Tensor,
    keep: torch.Tensor,
    c2w: torch.Tensor,
    intr: torch.Tensor,
    tol_px: float = TOL_PX,
    margin: float = MARGIN,
) -> torch.Tensor:
    """Which per-pixel Gaussians another input view covers more squarely (see the module docstring).

    means (N, 3) and normals (N, 3) (world, unit; zero = unknown: never dominated nor dominating), keep (N,) bool
    (the foreground pixels' Gaussians), c2w (V, 4, 4), intr (V, 4) of square-pixel views. Returns (N,) bool."""
    V = c2w.shape[0]
    N = means.shape[0]
    H = W = int(round((N // V) ** 0.5))
    assert V * H * W == N and means.shape == (N, 3) and normals.shape == (N, 3), (means.shape, normals.shape, V)
    assert keep.shape == (N,) and intr.shape == (V, 4), (keep.shape, intr.shape)
    c2w, intr, means, normals = c2w.float(), intr.float(), means.float(), normals.float()
    _, d = camera.pixel_rays(c2w, intr, H, W)
    cos = (normals * d.reshape(N, 3)).sum(-1).abs()  # (N,) how squarely each Gaussian's own view sees it
    has_n = normals.norm(dim=-1) > 0.5
    valid = keep.bool() & has_n
    dev = means.device
    view = torch.arange(V, device=dev).repeat_interleave(H * W)
    uv, z = camera.project(means, c2w, intr)  # (V, N, 2), (V, N): every Gaussian in every view
    z_own = z[view, torch.arange(N, device=dev)].reshape(V, H, W)  # each pixel's own Gaussian's depth in its view
    z_own = torch.where(valid.reshape(V, H, W), z_own, torch.full_like(z_own, float("nan")))
    cos_map = torch.where(valid, cos, torch.zeros_like(cos)).reshape(V, H, W)
    out = torch.zeros(N, dtype=torch.bool, device=dev)
    for j in range(V):
        col = uv[j, :, 0].floor().long()
        row = uv[j, :, 1].floor().long()
        inside = (col >= 0) & (col < W) & (row >= 0) & (row < H) & (z[j] > 0) & valid & (view != j)
        r, c = row.clamp(0, H - 1), col.clamp(0, W - 1)
        zj, cj = z_own[j, r, c], cos_map[j, r, c]
        footprint = zj / intr[j, 0]  # one pixel of view j at that depth, in world units
        same = (z[j] - zj).abs() < tol_px * footprint / cj.clamp_min(0.25)
        out |= inside & same & (cj > cos + margin)
    return out


def frontal_keep(
    means: torch.Tensor, keep: torch.Tensor, c2w: torch.Tensor, intr: torch.Tensor, normals: torch.Tensor | None = None
) -> torch.Tensor:
    """keep (N,) bool of per-pixel Gaussians (means (N, 3) on the input pixel grid of views c2w (V, 4, 4), intr (V, 4))
    without the dominated ones (:func:`dominated`). normals: their world normals (N, 3) or (V, H, W, 3); None: from the
    means (:func:`frng.priors.surfels.grid_normals`)."""
    from frng.priors.surfels import grid_normals

    normals = grid_normals(means, keep, c2w) if normals is None else normals
    return keep & ~dominated(means, normals.reshape(-1, 3), keep, c2w, intr)


__all__ = ["MARGIN", "TOL_PX", "dominated", "frontal_keep"]
