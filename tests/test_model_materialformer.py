"""MaterialFormer / MatDetokenizer (paper Sec. 4.2.1) and the light-independence loss (Sec. 4.2.2)."""

import numpy as np
import pytest
import torch

from frng import camera
from frng.gaussians import Gaussians, pixel_gaussians
from frng.model import (
    FineGeometry,
    FineGeometryConfig,
    LightIndependenceConfig,
    MaterialFormer,
    MaterialFormerConfig,
    MaterialHead,
    PriorTokenizer,
    coarse_features_to_pixels,
    decode_pbr,
    light_independence_loss,
    select_top_k,
    split_sequence,
    to_sequence,
)
from frng.model.light_independence import cosine_term, kld_term

SMALL = dict(geo_dim=32, app_dim=24, prior_dim=16, hidden=32, depth=2, heads=4, patch=8, feature_dim=6)


def rig(V, size):
    eyes = [camera.spherical_to_cartesian(360.0 * v / V, 20.0 * (v % 2), 2.6) for v in range(V)]
    c2w = torch.tensor(np.stack([camera.look_at(e) for e in eyes]), dtype=torch.float32)
    intr = torch.tensor(camera.intrinsics_from_fov(50, size, size), dtype=torch.float32).expand(V, 4).contiguous()
    return c2w, intr


@pytest.mark.parametrize("V", [2, 3, 4, 6, 8, 10])
def test_end_to_end_shapes_and_gradients(V):
    """Prior tokenizer -> fine geometry -> MaterialFormer -> per-Gaussian features + L_ind, for V views."""
    torch.manual_seed(V)
    size, p = 32, 8
    h = w = size // p
    c2w, intr = rig(V, size)
    t_geo = torch.randn(V, h, w, SMALL["geo_dim"])  # frozen backbone outputs (cached): no grad
    t_app, t_app1 = torch.randn(2, V, h, w, SMALL["app_dim"])
    raw_coarse = torch.randn(V, size, size, 9)
    priors = torch.rand(V, size, size, 8)

    tokenizer = PriorTokenizer(SMALL["prior_dim"], p)
    fine = FineGeometry(FineGeometryConfig(upsample=2, patch=p, geo_dim=SMALL["geo_dim"], prior_dim=SMALL["prior_dim"]))
    head = MaterialHead(MaterialFormerConfig(**SMALL))

    t_prior = tokenizer(priors)
    idx = select_top_k(torch.rand(V, h, w), 0.125)  # 2 patches per view
    fo = fine(t_geo, idx, c2w, intr, t_prior)
    M = fo.t_geo.shape[1]
    seq_geo = to_sequence(t_geo, fo.t_geo)
    seq_prior = to_sequence(t_prior, fo.t_prior)
    seq_app = to_sequence(t_app, fine.interpolate(t_app, idx))
    seq_app1 = to_sequence(t_app1, fine.interpolate(t_app1, idx))
    L = V * h * w + V * M
    assert seq_geo.shape == (1, L, SMALL["geo_dim"]) and seq_prior.shape == (1, L, SMALL["prior_dim"])

    t_mat, g_mat = head(seq_geo, seq_app, seq_prior)
    t_mat1, _ = head(seq_geo, seq_app1, seq_prior)
    assert t_mat.shape == (1, L, SMALL["hidden"]) and g_mat.shape == (1, L, p * p, SMALL["feature_dim"])

    coarse_f, fine_f = split_sequence(g_mat, V, h, w)
    feats = torch.cat([coarse_features_to_pixels(coarse_f[0], p).reshape(-1, 6), fine_f[0].reshape(-1, 6)])
    gs = Gaussians.cat([pixel_gaussians(raw_coarse, c2w, intr), fo.gaussians]).with_features(feats)
    assert len(gs) == V * size * size + V * M * p * p

    l_ind, parts = light_independence_loss(t_mat, t_mat1)
    loss = (gs.features**2).mean() + gs.means.square().mean() + l_ind
    loss.backward()
    assert l_ind.item() > 0 and parts["cos"] > 0 and parts["kld"] > 0
    for name, mod in [("tokenizer", tokenizer), ("fine", fine), ("head", head)]:
        for pn, prm in mod.named_parameters():
            assert prm.grad is not None and prm.grad.abs().sum() > 0, f"no gradient reaches {name}.{pn}"
    assert not t_geo.requires_grad  # cached backbone tokens stay leaves without grad


def test_coarse_features_align_with_pixel_gaussians():
    V, h, w, p = 2, 3, 4, 8
    feats = torch.randn(V, h, w, p * p, 5)
    pix = coarse_features_to_pixels(feats, p)
    assert pix.shape == (V, h * p, w * p, 5)
    # Gaussian (y, x) of token (i, j) is pixel (i p + y, j p + x)
    assert torch.equal(pix[1, 2 * p + 3, 1 * p + 6], feats[1, 2, 1, 3 * p + 6])


def test_sequence_roundtrip_batched():
    B, V, h, w, M, D = 2, 3, 2, 2, 4, 5
    c, f = torch.randn(B, V, h, w, D), torch.randn(B, V, M, D)
    seq = to_sequence(c, f)
    assert seq.shape == (B, V * h * w + V * M, D)
    c2, f2 = split_sequence(seq, V, h, w)
    assert torch.equal(c2, c) and torch.equal(f2, f)
    assert to_sequence(c).shape == (B, V * h * w, D)


def test_no_idm_variant_has_no_prior_path():
    cfg = MaterialFormerConfig(**{**SMALL, "prior_dim": 0})
    mf = MaterialFormer(cfg)
    assert not mf.uses_priors and not any("prior" in n for n, _ in mf.named_parameters())
    x_geo, x_app = torch.randn(1, 10, 32), torch.randn(1, 10, 24)
    assert mf(x_geo, x_app).shape == (1, 10, 32)
    with pytest.raises(ValueError):
        mf(x_geo, x_app, torch.randn(1, 10, 16))
    with pytest.raises(ValueError):
        MaterialFormer(MaterialFormerConfig(**SMALL))(x_geo, x_app)  # priors required when built with them


def test_pbr_head_for_no_neural_ablation():
    head = MaterialHead(MaterialFormerConfig(**{**SMALL, "head": "pbr"}))
    _, g = head(torch.randn(2, 7, 32), torch.randn(2, 7, 24), torch.randn(2, 7, 16))
    assert g.shape == (2, 7, 64, 8)
    pbr = decode_pbr(g)
    assert pbr["albedo"].shape == (2, 7, 64, 3) and pbr["normal"].shape == (2, 7, 64, 3)
    assert ((pbr["albedo"] > 0) & (pbr["albedo"] < 1)).all()
    assert (pbr["roughness"] >= 0.02).all() and (pbr["metallic"] <= 1).all()
    torch.testing.assert_close(pbr["normal"].norm(dim=-1), torch.ones(2, 7, 64))
    with pytest.raises(ValueError):
        MaterialFormerConfig(head="ggx")


def test_bf16_autocast():
    torch.manual_seed(0)
    head = MaterialHead(MaterialFormerConfig(**SMALL))
    args = (torch.randn(1, 12, 32), torch.randn(1, 12, 24), torch.randn(1, 12, 16))
    with torch.autocast("cpu", dtype=torch.bfloat16):
        t_mat, g = head(*args)
        loss, _ = light_independence_loss(t_mat, t_mat.roll(1, dims=1))
    assert g.dtype == torch.bfloat16 and torch.isfinite(g.float()).all()
    assert loss.dtype == torch.float32 and torch.isfinite(loss)
    loss.backward()
    assert head.former.in_proj.weight.grad is not None
    t32, _ = head(*args)
    torch.testing.assert_close(t_mat.float(), t32, atol=0.1, rtol=0.05)


def test_light_independence_zero_iff_identical():
    torch.manual_seed(0)
    a = torch.randn(2, 50, 32)
    loss, parts = light_independence_loss(a, a.clone())
    assert loss.item() < 1e-6 and parts["cos"].item() < 1e-6 and parts["kld"].item() == 0.0
    b = a + 0.3 * torch.randn_like(a)
    loss_b, parts_b = light_independence_loss(a, b)
    assert loss_b > 1e-3 and parts_b["cos"] > 0 and parts_b["kld"] > 0
    # each term catches what the other cannot: a positive rescale (cosine 0, KL > 0), a shift (KL 0, cosine > 0)
    assert cosine_term(a, 2 * a) < 1e-6 and kld_term(a, 2 * a) > 1e-3
    assert kld_term(a, a + 1.0) < 1e-6 and cosine_term(a, a + 1.0) > 1e-3
    # symmetric, larger for larger differences; weights as configured (paper 0.2 / 0.2)
    torch.testing.assert_close(light_independence_loss(b, a)[0], loss_b)
    assert light_independence_loss(a, a + 1.0 * torch.randn_like(a))[0] > loss_b
    torch.testing.assert_close(loss_b, 0.2 * parts_b["cos"] + 0.2 * parts_b["kld"])
    zero, _ = light_independence_loss(a, b, LightIndependenceConfig(lambda_c=0.0, lambda_kld=0.0))
    assert zero.item() == 0.0
    # gradients reach both sides
    x, y = a.clone().requires_grad_(), b.clone().requires_grad_()
    light_independence_loss(x, y)[0].backward()
    assert x.grad.abs().sum() > 0 and y.grad.abs().sum() > 0


def test_light_independence_adds_the_per_gaussian_payload():
    """With payloads (train.loss.ind_pixels) each term is its token value plus its payload value; identical payloads
    add nothing, different ones add exactly their own cosine and KL terms, with gradients into both."""
    torch.manual_seed(0)
    a = torch.randn(1, 40, 32)
    b = a + 0.3 * torch.randn_like(a)
    m = torch.randn(500, 16)
    tokens_only, p0 = light_independence_loss(a, b)
    same, p1 = light_independence_loss(a, b, None, m, m.clone())
    torch.testing.assert_close(same, tokens_only)
    m2 = (m + 0.5 * torch.randn_like(m)).requires_grad_()
    m1 = m.clone().requires_grad_()
    loss, parts = light_independence_loss(a, b, None, m1, m2)
    torch.testing.assert_close(parts["cos"], p0["cos"] + cosine_term(m, m2.detach()))
    torch.testing.assert_close(parts["kld"], p0["kld"] + kld_term(m, m2.detach()))
    assert loss > tokens_only
    loss.backward()
    assert m1.grad.abs().sum() > 0 and m2.grad.abs().sum() > 0


def test_kept_rows_gather_what_the_reference_path_gathers():
    """One index_select with kept_rows = slice, unpatchify and the two keep-mask gathers (coarse, then fine)."""
    from frng.model.materialformer import kept_rows

    V, h, w, p, M, C = 3, 2, 4, 3, 5, 7
    P = p * p
    g = torch.randn(V * h * w + V * M, P, C)
    gen = torch.Generator().manual_seed(0)
    keep_c = torch.rand(V * h * p * w * p, generator=gen) > 0.4
    keep_f = torch.rand(V * M * P, generator=gen) > 0.6
    coarse, fine = split_sequence(g[None], V, h, w)
    ref = torch.cat([coarse_features_to_pixels(coarse[0], p).reshape(-1, C)[keep_c], fine[0].reshape(-1, C)[keep_f]])
    assert torch.equal(g.reshape(-1, C).index_select(0, kept_rows(keep_c, keep_f, V, h, w, p)), ref)
    ref_c = coarse_features_to_pixels(coarse[0], p).reshape(-1, C)[keep_c]
    assert torch.equal(g.reshape(-1, C)[kept_rows(keep_c, None, V, h, w, p)], ref_c)
