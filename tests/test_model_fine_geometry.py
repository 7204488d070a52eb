"""Latent-interpolated fine-grained geometry synthesis (paper Sec. 4.1) and the prior tokenizer."""

import numpy as np
import pytest
import torch
import torch.nn.functional as F

from frng import camera
from frng.gaussians import GaussianDecodeConfig
from frng.model.fine_geometry import (
    FineGeoDetokenizer,
    FineGeometry,
    FineGeometryConfig,
    bilinear_tokens,
    fine_gaussian_uv,
    fine_keep_mask,
    fine_positions,
)
from frng.model.saliency import select_top_k
from frng.model.tokenizers import PRIOR_CHANNELS, PriorTokenizer, patchify, stack_priors, unpatchify
from frng.nn import PatchDetokenizer


def rig(V, size):
    eyes = [camera.spherical_to_cartesian(360.0 * v / V, 15.0 * (v % 2), 2.6) for v in range(V)]
    c2w = torch.tensor(np.stack([camera.look_at(e) for e in eyes]), dtype=torch.float32)
    intr = torch.tensor(camera.intrinsics_from_fov(50, size, size), dtype=torch.float32).expand(V, 4).contiguous()
    return c2w, intr


def test_interpolation_at_integer_positions_is_exact():
    torch.manual_seed(0)
    tok = torch.randn(3, 4, 5, 16)
    rows, cols = torch.meshgrid(torch.arange(4), torch.arange(5), indexing="ij")
    pos = torch.stack([rows, cols], -1).reshape(1, 20, 2).float().expand(3, -1, -1)
    out = bilinear_tokens(tok, pos)
    assert torch.equal(out, tok.reshape(3, 20, 16))
    # odd upsampling: the centre sub-patch sits on the patch centre -> the original token, bit-exact
    idx = torch.tensor([[0, 7, 19], [3, 4, 12], [1, 2, 18]])
    fine = bilinear_tokens(tok, fine_positions(idx, 5, 3)).reshape(3, 3, 9, 16)
    assert torch.equal(fine[:, :, 4], torch.gather(tok.reshape(3, 20, 16), 1, idx[..., None].expand(-1, -1, 16)))


def test_interpolation_matches_grid_sample_and_is_bilinear():
    torch.manual_seed(1)
    V, h, w, D = 2, 4, 6, 8
    tok = torch.randn(V, h, w, D, dtype=torch.float64)
    pos = torch.rand(V, 50, 2, dtype=torch.float64) * torch.tensor([h - 1, w - 1], dtype=torch.float64)
    ours = bilinear_tokens(tok, pos)
    # grid_sample with align_corners=True puts token (i, j) at normalised (2j/(w-1) - 1, 2i/(h-1) - 1)
    grid = torch.stack([pos[..., 1] / (w - 1) * 2 - 1, pos[..., 0] / (h - 1) * 2 - 1], -1)[:, None]
    ref = F.grid_sample(tok.permute(0, 3, 1, 2), grid, align_corners=True, padding_mode="border")
    torch.testing.assert_close(ours, ref[:, :, 0].permute(0, 2, 1))
    # border clamp: positions outside the grid take the border value
    out = bilinear_tokens(
        tok, torch.tensor([[[-0.25, -0.25], [h - 0.75, w - 0.75]]], dtype=torch.float64).expand(V, -1, -1)
    )
    torch.testing.assert_close(out[:, 0], tok[:, 0, 0])
    torch.testing.assert_close(out[:, 1], tok[:, -1, -1])


def test_fine_positions_and_uv_layout():
    idx = torch.tensor([[9]])  # w = 4 -> patch (2, 1)
    pos = fine_positions(idx, 4, 2)
    assert pos.tolist() == [[[1.75, 0.75], [1.75, 1.25], [2.25, 0.75], [2.25, 1.25]]]
    uv = fine_gaussian_uv(idx, 4, 8, 2)  # (1, 4, 64, 2)
    assert uv.shape == (1, 4, 64, 2)
    # all Gaussians inside the patch's pixels [8, 16) x [16, 24), on a 0.5-px grid, 4 fine tokens tile the patch
    assert uv[..., 0].min() == 8.25 and uv[..., 0].max() == 15.75
    assert uv[..., 1].min() == 16.25 and uv[..., 1].max() == 23.75
    assert len({tuple(p) for p in uv.reshape(-1, 2).tolist()}) == 256
    # fine token (a=0, b=1) covers cols [12, 16), rows [16, 20); Gaussian order y*p + x
    t = uv[0, 1].reshape(8, 8, 2)
    assert (
        t[0, 0].tolist() == [12.25, 16.25] and t[0, 1].tolist() == [12.75, 16.25] and t[1, 0].tolist() == [12.25, 16.75]
    )


@pytest.mark.parametrize("V", [2, 6, 10])
def test_fine_gaussians_on_sub_pixel_rays(V):
    torch.manual_seed(V)
    size, p, D, Dp = 32, 8, 32, 12
    h = w = size // p
    c2w, intr = rig(V, size)
    t_geo, t_prior = torch.randn(V, h, w, D), torch.randn(V, h, w, Dp)
    idx = select_top_k(torch.rand(V, h, w), 0.1)  # ceil(1.6) = 2 patches per view
    fg = FineGeometry(FineGeometryConfig(upsample=2, patch=p, geo_dim=D, prior_dim=Dp))
    out = fg(t_geo, idx, c2w, intr, t_prior)
    M = 2 * 4
    assert out.t_geo.shape == (V, M, D) and out.t_prior.shape == (V, M, Dp)
    assert out.raw.shape == (V, M, p * p, 9) and len(out.gaussians) == V * M * p * p
    # every mean projects back onto its sub-pixel position in its own view, in front of the camera
    uv, z = camera.project(out.gaussians.means.reshape(V, M * p * p, 3), c2w, intr)
    torch.testing.assert_close(uv, out.uv.reshape(V, -1, 2), atol=2e-3, rtol=0)
    assert (z > 0).all()
    # ... and lies on the ray rays_at gives for that position
    o, d = camera.rays_at(c2w, intr, out.uv)
    rel = out.gaussians.means.reshape(V, M, p * p, 3) - o
    torch.testing.assert_close(torch.cross(rel, d, dim=-1), torch.zeros_like(rel), atol=1e-4, rtol=0)
    # fine Gaussians stay inside their selected patch
    rows, cols = idx // w, idx % w
    px = out.uv.reshape(V, -1, 4 * p * p, 2)
    assert ((px[..., 0] >= cols[..., None] * p) & (px[..., 0] < (cols[..., None] + 1) * p)).all()
    assert ((px[..., 1] >= rows[..., None] * p) & (px[..., 1] < (rows[..., None] + 1) * p)).all()
    # appearance tokens interpolated at the same positions
    assert torch.equal(fg.interpolate(t_geo, idx), out.t_geo)


def test_init_from_backbone_detokenizer_and_scale_shrink():
    torch.manual_seed(3)
    D, p = 16, 8
    geo_det = PatchDetokenizer(D, 9, p)
    with torch.no_grad():
        geo_det.norm.weight.uniform_(0.5, 1.5)
        geo_det.norm.bias.normal_()
    fine = FineGeoDetokenizer(D, 4, p).init_from(geo_det)
    tok = torch.randn(2, 3, 3, D)
    coarse_raw = patchify(geo_det(tok), p).reshape(2, 3, 3, p * p, 9)
    torch.testing.assert_close(fine(tok, torch.randn(2, 3, 3, 4)), coarse_raw)
    # at init, a fine Gaussian with the same raw scale is s times smaller than a coarse one
    fg = FineGeometry(FineGeometryConfig(upsample=2, geo_dim=D, prior_dim=0), GaussianDecodeConfig(near=1.5, far=3.5))
    assert fg.decode_cfg.near == 1.5 and abs(fg.decode_cfg.scale_offset - (2.3 + np.log(2))) < 1e-9


def test_no_prior_variant_never_reads_priors():
    det = FineGeoDetokenizer(8, 0)
    assert det.norm_prior is None and det.proj.in_features == 8
    with pytest.raises(ValueError):
        det(torch.randn(3, 8), torch.randn(3, 4))
    with pytest.raises(ValueError):
        FineGeoDetokenizer(8, 4)(torch.randn(3, 8))
    with pytest.raises(ValueError):
        FineGeometryConfig(upsample=3, patch=8)


def test_prior_tokenizer_and_patchify_roundtrip():
    torch.manual_seed(0)
    V, H, W = 3, 16, 24
    priors = {
        "normal": torch.randn(V, H, W, 3),
        "albedo": torch.rand(V, H, W, 3),
        "roughness": torch.rand(V, H, W),
        "metallic": torch.rand(V, H, W, 1),
        "depth": torch.rand(V, H, W),
    }
    x = stack_priors(priors)
    assert x.shape == (V, H, W, PRIOR_CHANNELS)
    assert torch.equal(x[..., 6], priors["roughness"]) and torch.equal(x[..., 3:6], priors["albedo"])
    patches = patchify(x, 8)
    assert patches.shape == (V, 2, 3, 64 * 8)
    assert torch.equal(unpatchify(patches, 8, 8), x)
    # pixel (y, x) of patch (i, j) lands at (y*p + x)*C + c
    assert torch.equal(patches[1, 1, 2, (3 * 8 + 5) * 8 : (3 * 8 + 5) * 8 + 8], x[1, 8 + 3, 16 + 5])
    tok = PriorTokenizer(32, 8)
    t = tok(x)
    assert t.shape == (V, 2, 3, 32)
    torch.testing.assert_close(t, patches @ tok.proj.weight.T + tok.proj.bias)
    assert tok(x[None]).shape == (1, V, 2, 3, 32)  # batch dim in front
    with pytest.raises(KeyError):
        stack_priors({"normal": priors["normal"]})


def test_fine_keep_mask_follows_pixel_mask():
    idx = torch.tensor([[0, 5], [3, 6]])  # 4x4 patch grid on 32x32 views
    uv = fine_gaussian_uv(idx, 4, 8, 2)
    mask = torch.zeros(2, 32, 32, dtype=torch.bool)
    mask[:, :, 12:] = True  # right part of the image is foreground
    keep = fine_keep_mask(uv, mask).reshape(2, 8, 64)
    assert torch.equal(keep, (uv[..., 0] >= 12))
    assert not keep[0, :4].any() and keep[1, :4].all()  # patch 0 (cols 0-7) out, patch 3 (cols 24-31) in
