"""Per-Gaussian depth refinement of the frozen backbone's geometry (our addition; ``frng.depth_head``).

F-RNG renders the backbone's per-pixel Gaussians at the ray distance the backbone predicted for their input pixel
(paper Sec. 4.1). Where the six views' visual hull is wrong (a thin slab seen obliquely, a concavity) the backbone
mostly keeps the hull's depth. The depth head lets F-RNG move each of those coarse Gaussians along its input ray,
from what F-RNG knows of it (its detokenizer output ``g`` and input pixel ``pixel``, as the opacity head reads them
without ``frng.geometry_inputs``):

    mean' = mean + max_offset * tanh(MLP([g, pixel])) * (mean - origin) / |mean - origin|

with ``origin`` the input camera's centre and ``max_offset`` (``frng.depth_head``, world units; the object's radius
is 1) bounding the move. The last layer starts at zero (an untrained head moves nothing); it is trained by F-RNG's
own losses through the rasterizer's gradients on the means. The fine Gaussians (F-RNG's own geometry) and the
far-side copies are not moved.

:func:`at_distances` puts the same coarse Gaussians at given distances along their rays instead: with the G-buffer's
surface distances (``frng train --geometry gbuffer``, ``frng bench heldout --geometry gbuffer``) it measures what
F-RNG would gain from exact geometry where its inputs see the surface (docs/model-and-training.md, "Geometry gap").
"""

from __future__ import annotations

import torch
from torch.nn import functional as F

from frng.model.opacity import GaussianResidual


class DepthHead(GaussianResidual):
    """A bounded offset of each coarse Gaussian along its input ray (the module docstring)."""

    def __init__(self, out_channels: int, pixel_channels: int, hidden: int, max_offset: float):
        super().__init__(out_channels, pixel_channels, hidden)
        if not max_offset > 0:
            raise ValueError(f"DepthHead: max_offset must be > 0, got {max_offset}")
        self.max_offset = float(max_offset)

    def offset(self, g: torch.Tensor, pixel: torch.Tensor) -> torch.Tensor:
        """g (N, C_out), pixel (N, C_pix) -> (N,) offsets in (-max_offset, max_offset) world units."""
        return self.max_offset * torch.tanh(self.residual(g, pixel).float())

    @staticmethod
    def origins(c2w: torch.Tensor, keep: torch.Tensor) -> torch.Tensor:
        """Each kept coarse Gaussian's input camera centre: c2w (V, 4, 4), keep (N,) bool over the N = V*H*W pixels
        in view order -> (K, 3), K = keep.sum()."""
        assert c2w.dim() == 3 and keep.dim() == 1 and keep.numel() % c2w.shape[0] == 0, (c2w.shape, keep.shape)
        return c2w[:, :3, 3].repeat_interleave(keep.numel() // c2w.shape[0], 0)[keep]

    @staticmethod
    def move(means: torch.Tensor, origins: torch.Tensor, offset: torch.Tensor) -> torch.Tensor:
        """means (N, 3), origins (N, 3) their input cameras' centres, offset (N,) -> (N, 3) moved along the rays."""
        assert means.shape == origins.shape and means.shape[-1] == 3 and offset.shape == means.shape[:1], (
            means.shape,
            origins.shape,
            offset.shape,
        )
        return means + F.normalize(means - origins, dim=-1) * offset[:, None].to(means.dtype)


def at_distances(means: torch.Tensor, c2w: torch.Tensor, distance: torch.Tensor) -> torch.Tensor:
    """Per-pixel Gaussians put at given distances along their input rays.

    means (N, 3) one Gaussian per input pixel, N = V*H*W in view order (the backbone cache's ``means``, each on its
    pixel's ray); c2w (V, 4, 4) the input cameras; distance (N,) the distance from the pixel's camera centre at which
    its Gaussian goes, <= 0 where there is none (that Gaussian keeps its mean). Returns (N, 3)."""
    assert means.dim() == 2 and means.shape[-1] == 3 and distance.shape == means.shape[:1], (
        means.shape,
        distance.shape,
    )
    origins = DepthHead.origins(c2w.to(means.dtype), torch.ones(means.shape[0], dtype=torch.bool))
    rays = F.normalize(means - origins, dim=-1)
    moved = origins + rays * distance[:, None].to(means.dtype)
    return torch.where((distance > 0)[:, None], moved, means)


__all__ = ["DepthHead", "at_distances"]
