"""Pixel-footprint surfels (frng.priors.surfels), the mirrored far-side copies (frng.priors.multiview.mirror_quats) and the
quality ladder's ground-truth-depth surfels (frng.priors.evaluate.gt_depth_gaussians): point-like per-pixel
Gaussians of a surface seen at a grazing angle leave the background showing through from above; surfels close it."""

from types import SimpleNamespace

import numpy as np
import torch

from frng import camera
from frng.gaussians import GaussianDecodeConfig, Gaussians
from frng.priors.evaluate import gt_depth_gaussians
from frng.priors.multiview import mirror_quats
from frng.priors.surfels import PIXEL_STD, THICKNESS, grid_normals, pixel_surfels, surfel_shapes
from frng.render import rasterize
from frng.render.project import covariance_3d, quat_to_rotmat, rotmat_to_quat


def _plane_view(elevation_deg: float, size: int = 32):
    """One camera looking at the square |x|, |y| <= 0.5 of the plane z = 0 from ``elevation_deg`` above it: c2w
    (1, 4, 4), intr (1, 4), its pixel rays o, d (1, size, size, 3), their distance t to the plane and ``inside``
    (1, size, size) bool: the ray hits the square."""
    eye = camera.spherical_to_cartesian(0.0, elevation_deg, 2.5)
    c2w = torch.tensor(camera.look_at(eye), dtype=torch.float32)[None]
    intr = torch.tensor(camera.intrinsics_from_fov(40.0, size, size), dtype=torch.float32)[None]
    o, d = camera.pixel_rays(c2w, intr, size, size)
    t = -o[..., 2] / d[..., 2]
    hit = o + t[..., None] * d
    inside = (hit[..., 0].abs() <= 0.5) & (hit[..., 1].abs() <= 0.5) & (t > 0)
    return c2w, intr, o, d, t, inside


def _plane_points(elevation_deg: float, size: int = 32):
    """Point-like per-pixel Gaussians on the plane of :func:`_plane_view` (std 0.002, as the backbone learns them),
    the keep mask and the camera."""
    c2w, intr, o, d, t, inside = _plane_view(elevation_deg, size)
    hit = o + t[..., None] * d
    keep = inside.reshape(-1)
    means = torch.where(keep[:, None], hit.reshape(-1, 3), o.reshape(-1, 3) + d.reshape(-1, 3))
    N = means.shape[0]
    g = Gaussians(means, torch.tensor([1.0, 0, 0, 0]).expand(N, 4), torch.full((N, 3), 0.002), torch.full((N,), 0.95))
    return g, keep, c2w, intr


def _plane_gbuffer(elevation_deg: float, size: int = 32):
    """The view of :func:`_plane_view` as a rig and its G-buffer (camera-z depth, world normal +z, mask)."""
    c2w, intr, o, d, t, inside = _plane_view(elevation_deg, size)
    zc = (t[..., None] * d * c2w[:, None, None, :3, 2]).sum(-1, keepdim=True)  # camera-axis depth
    mask = inside[..., None].float()
    normal = torch.tensor([0.0, 0.0, 1.0]).expand(1, size, size, 3) * mask
    rig = SimpleNamespace(alpha=mask, c2w=c2w, intr=intr)
    gbuffer = SimpleNamespace(depth=zc * mask, normal=normal, mask=mask)
    return rig, gbuffer


def _alpha_from_above(g: Gaussians, size: int = 32) -> tuple[torch.Tensor, torch.Tensor]:
    top = torch.tensor(camera.look_at(camera.spherical_to_cartesian(0.0, 89.0, 2.5)), dtype=torch.float32)[None]
    intr = torch.tensor(camera.intrinsics_from_fov(40.0, size, size), dtype=torch.float32)[None]
    _, alpha, _ = rasterize(g.means, g.quats, g.scales, g.opacities, torch.ones(len(g.means), 3), top, intr, size, size)
    uv, _ = camera.project(g.means, top, intr)
    return alpha[0, ..., 0], uv[0]


def _inner(alpha: torch.Tensor, uv: torch.Tensor) -> torch.Tensor:
    """The alpha of the middle of the region the Gaussians project to (20-80 % quantiles in u and v)."""
    lo_u, hi_u = np.quantile(uv[:, 0].numpy(), [0.2, 0.8])
    lo_v, hi_v = np.quantile(uv[:, 1].numpy(), [0.2, 0.8])
    return alpha[int(lo_v) + 1 : int(hi_v), int(lo_u) + 1 : int(hi_u)]


def test_surfels_close_a_grazing_surface_that_points_leave_open():
    g, keep, c2w, intr = _plane_points(elevation_deg=15.0)  # the view sees the plane 75 degrees off its normal
    assert int(keep.sum()) > 50
    a_pts, uv = _alpha_from_above(g[keep])
    inner_pts = _inner(a_pts, uv)
    assert inner_pts.numel() > 20
    assert float(inner_pts.min()) < 0.3, "control: point-like Gaussians should leave gaps from above"
    s = pixel_surfels(g, keep, c2w, intr)[keep]
    assert torch.equal(s.means, g.means[keep]) and torch.equal(s.opacities, g.opacities[keep])
    # flat in the plane (thinnest axis along +-z), stretched along the tilt (at most 4x)
    R = quat_to_rotmat(s.quats)
    thin = R[torch.arange(len(s.scales)), :, s.scales.argmin(-1)]
    inner_rows = thin[:, 2].abs() > 0.99
    assert float(inner_rows.float().mean()) > 0.8  # the silhouette's rim has one-sided normals
    ratio = s.scales.max(-1).values / s.scales.median(-1).values
    assert float(ratio.median()) > 3.0 and float(ratio.max()) <= 4.0 + 1e-4
    a_surf, uv = _alpha_from_above(s)
    inner = _inner(a_surf, uv)
    assert float(inner.min()) > 0.5, f"holes in the covered region: min alpha {float(inner.min()):.3f}"


def test_surfel_shapes_face_on_is_a_pixel_wide_disc():
    n = torch.tensor([[0.0, 0.0, 1.0], [0.0, 0.6, 0.8]])
    d = -n  # looked at straight on
    q, sc = surfel_shapes(n, d, torch.tensor([0.01, 0.02]))
    assert torch.allclose(sc, torch.tensor([[0.01, 0.01, 0.01 * THICKNESS], [0.02, 0.02, 0.02 * THICKNESS]]))
    assert torch.allclose(quat_to_rotmat(q)[:, :, 2], n, atol=1e-5)


def test_grid_normals_of_a_plane():
    g, keep, c2w, _ = _plane_points(elevation_deg=40.0)
    n = grid_normals(g.means, keep, c2w).reshape(-1, 3)[keep]
    assert float((n[:, 2] > 0.999).float().mean()) > 0.9  # +z: the side facing the camera above the plane


def test_mirror_quats_reflect_the_covariance():
    gen = torch.Generator().manual_seed(0)
    q = torch.randn(64, 4, generator=gen)
    sc = torch.rand(64, 3, generator=gen) + 0.1
    d = torch.randn(64, 3, generator=gen)
    d = d / d.norm(dim=-1, keepdim=True)
    H = torch.eye(3) - 2 * d[:, :, None] * d[:, None, :]
    want = H @ covariance_3d(q, sc) @ H
    qm = mirror_quats(q, d)
    assert torch.allclose(covariance_3d(qm, sc), want, atol=1e-5)
    assert torch.allclose(torch.linalg.det(quat_to_rotmat(qm)), torch.ones(64), atol=1e-5)


def test_rotmat_to_quat_inverts_quat_to_rotmat():
    g = torch.Generator().manual_seed(0)
    q = torch.randn(2000, 4, generator=g)
    q = q / q.norm(dim=-1, keepdim=True)
    q = torch.where(q[:, :1] < 0, -q, q)
    # include the branches where x, y or z dominates and the trace is negative
    q = torch.cat([q, torch.tensor([[0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 0.0, 1.0]])])
    back = rotmat_to_quat(quat_to_rotmat(q))
    assert torch.allclose(back, q, atol=1e-5)


def test_ceiling_surfels_cover_a_grazing_surface_seen_from_above():
    rig, gbuffer = _plane_gbuffer(elevation_deg=15.0)  # the input view sees the plane 75 degrees off its normal
    gauss, keep = gt_depth_gaussians(rig, gbuffer, PIXEL_STD, GaussianDecodeConfig())
    assert int(keep.sum()) > 50
    g = gauss[keep]
    R = quat_to_rotmat(g.quats)
    # flat in the plane: the thinnest axis is the normal (+-z)
    thin = R[torch.arange(len(g.scales)), :, g.scales.argmin(-1)]
    assert torch.allclose(thin[:, 2].abs(), torch.ones(len(thin)), atol=1e-4)
    # seen from straight above, the surfels cover the part of the square the input view saw without gaps
    alpha, uv = _alpha_from_above(g)
    inner = _inner(alpha, uv)
    assert inner.numel() > 20
    assert float(inner.min()) > 0.5, f"holes in the covered region: min alpha {float(inner.min()):.3f}"


def test_ladder_depth_error_is_the_mean_distance_error_on_the_rigs_foreground():
    """frng.priors.evaluate.depth_error: 0 for the ground-truth-depth Gaussians, the offset for Gaussians moved along
    their rays by it, and background pixels (no G-buffer depth) do not count."""
    from frng.priors.evaluate import depth_error

    rig, gbuffer = _plane_gbuffer(elevation_deg=40.0)
    gauss, _ = gt_depth_gaussians(rig, gbuffer, PIXEL_STD, GaussianDecodeConfig())
    assert abs(depth_error(gauss.means, rig, gbuffer)) < 1e-5
    o, d = camera.pixel_rays(rig.c2w, rig.intr, 32, 32)
    behind = gauss.means + 0.1 * d.reshape(-1, 3)  # every Gaussian 0.1 farther along its ray, background ones too
    assert abs(depth_error(behind, rig, gbuffer) - 0.1) < 1e-4
