"""The quality ladder's ground-truth-depth reference (frng.priors.evaluate.gt_depth_gaussians): surfels on the true
surface that cover it without gaps from other views, and the quaternion helper they use."""

from types import SimpleNamespace

import numpy as np
import torch

from frng import camera
from frng.gaussians import GaussianDecodeConfig
from frng.priors.evaluate import PIXEL_STD, gt_depth_gaussians
from frng.render import rasterize
from frng.render.project import quat_to_rotmat, rotmat_to_quat


def test_rotmat_to_quat_inverts_quat_to_rotmat():
    g = torch.Generator().manual_seed(0)
    q = torch.randn(2000, 4, generator=g)
    q = q / q.norm(dim=-1, keepdim=True)
    q = torch.where(q[:, :1] < 0, -q, q)
    # include the branches where x, y or z dominates and the trace is negative
    q = torch.cat([q, torch.tensor([[0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 0.0, 1.0]])])
    back = rotmat_to_quat(quat_to_rotmat(q))
    assert torch.allclose(back, q, atol=1e-5)


def _plane_rig(elevation_deg: float, size: int = 32):
    """A camera looking at the square |x|, |y| <= 0.5 on the plane z = 0 from ``elevation_deg`` above it, and the
    G-buffer of that view (camera-z depth, world normal +z, mask)."""
    eye = camera.spherical_to_cartesian(0.0, elevation_deg, 2.5)
    c2w = torch.tensor(camera.look_at(eye), dtype=torch.float32)[None]
    intr = torch.tensor(camera.intrinsics_from_fov(40.0, size, size), dtype=torch.float32)[None]
    o, d = camera.pixel_rays(c2w, intr, size, size)
    t = -o[..., 2] / d[..., 2]
    hit = o + t[..., None] * d
    inside = (hit[..., 0].abs() <= 0.5) & (hit[..., 1].abs() <= 0.5) & (t > 0)
    zc = (t[..., None] * d * c2w[:, None, None, :3, 2]).sum(-1, keepdim=True)  # camera-axis depth
    mask = inside[..., None].float()
    normal = torch.tensor([0.0, 0.0, 1.0]).expand(1, size, size, 3) * mask
    rig = SimpleNamespace(alpha=mask, c2w=c2w, intr=intr)
    gbuffer = SimpleNamespace(depth=zc * mask, normal=normal, mask=mask)
    return rig, gbuffer


def test_ceiling_surfels_cover_a_grazing_surface_seen_from_above():
    rig, gbuffer = _plane_rig(elevation_deg=15.0)  # the input view sees the plane 75 degrees off its normal
    gauss, keep = gt_depth_gaussians(rig, gbuffer, PIXEL_STD, GaussianDecodeConfig())
    assert int(keep.sum()) > 50
    g = gauss[keep]
    R = quat_to_rotmat(g.quats)
    # flat in the plane: the thinnest axis is the normal (+-z)
    thin = R[torch.arange(len(g.scales)), :, g.scales.argmin(-1)]
    assert torch.allclose(thin[:, 2].abs(), torch.ones(len(thin)), atol=1e-4)
    # seen from straight above, the surfels cover the part of the square the input view saw without gaps
    top = torch.tensor(camera.look_at(camera.spherical_to_cartesian(0.0, 89.0, 2.5)), dtype=torch.float32)[None]
    intr = torch.tensor(camera.intrinsics_from_fov(40.0, 32, 32), dtype=torch.float32)
    _, alpha, _ = rasterize(
        g.means, g.quats, g.scales, g.opacities, torch.ones(len(g.means), 3), top, intr[None], 32, 32
    )
    uv, _ = camera.project(g.means, top, intr[None])
    u, v = uv[0, :, 0], uv[0, :, 1]
    lo_u, hi_u = np.quantile(u.numpy(), [0.2, 0.8])
    lo_v, hi_v = np.quantile(v.numpy(), [0.2, 0.8])
    inner = alpha[0, int(lo_v) + 1 : int(hi_v), int(lo_u) + 1 : int(hi_u), 0]
    assert inner.numel() > 20
    assert float(inner.min()) > 0.5, f"holes in the covered region: min alpha {float(inner.min()):.3f}"
