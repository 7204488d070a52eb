"""Deferred shading: constant-BRDF and Lambertian decoders reproduce analytic integrals through the whole
pipeline (rasterize -> decode per pixel x light sample -> importance-sampled estimate); GGX furnace tests; the
spp_grad split gives the full estimate's value and the partial estimate's gradient."""

import math

import pytest
import torch

from frng.plan.sections import config_section
from frng.render import envmap, rasterize
from frng.render.shading import (
    NeuralDecoder,
    ShadingConfig,
    deferred_shade,
    ggx_diffuse_brdf,
    ggx_reflectance,
    lambert_sh,
    shade_pixels,
)

DT = torch.float64


def _scene():
    """Three big opaque Gaussians in front of a camera at the origin looking along +z; 2 views."""
    c2w = torch.eye(4, dtype=DT).repeat(2, 1, 1)
    c2w[1, :3, 3] = torch.tensor([0.05, 0.0, 0.0])
    K = torch.tensor([[16.0, 16.0, 8.0, 8.0]] * 2, dtype=DT)
    means = torch.tensor([[0.0, 0.0, 2.0], [0.3, 0.1, 2.2], [-0.3, -0.2, 2.4]], dtype=DT)
    quats = torch.tensor([[1.0, 0, 0, 0]] * 3, dtype=DT)
    scales = torch.full((3, 3), 0.25, dtype=DT)
    op = torch.tensor([0.95, 0.9, 0.9], dtype=DT)
    return means, quats, scales, op, c2w, K


def _band_limited_map(H=64):
    d = envmap.pixel_directions(H, 2 * H, dtype=DT)
    x, y, z = d.unbind(-1)
    base = 1.0 + 0.5 * z + 0.3 * x + 0.2 * (x * x - y * y)
    return torch.stack([base, 0.8 * base + 0.1 * y, 1.2 - 0.4 * z + 0.1 * x * z], -1)  # l <= 2, positive


def test_constant_brdf_decoder_reproduces_the_integral():
    means, quats, scales, op, c2w, K = _scene()
    feats = torch.randn(3, 8, dtype=DT)
    f, alpha, _ = rasterize(means, quats, scales, op, feats, c2w, K, 16, 16)
    rho = torch.tensor([0.2, 0.5, 0.7], dtype=DT)
    const = lambda feat, wo, wi: rho.expand(feat.shape[0], wi.shape[0], 3)  # noqa: E731
    grey = torch.full((16, 32, 3), 1.5, dtype=DT)
    grey[2:5, 4:9] = 40.0  # a bright grey sun: pdf proportional to L, so L / pdf is constant
    s = envmap.importance_sampler(grey, floor=0.0)
    smp = envmap.sample(s, 32)
    rgb = deferred_shade(const, [f], alpha, c2w, K, smp, alpha_eps=1e-3, background=torch.ones(3, dtype=DT))
    integral = (grey * envmap.pixel_solid_angles(16, 32)[..., None]).sum((0, 1))
    fg = alpha[..., 0] > 1e-3
    expect = alpha * rho * integral + (1 - alpha)
    assert fg.sum() > 50 and (~fg).sum() > 50
    assert torch.allclose(rgb[fg], expect[fg], rtol=1e-9)
    assert torch.allclose(rgb[~fg], (1 - alpha)[~fg].expand(-1, 3), atol=1e-12)  # background only


def test_lambertian_surface_matches_sh_irradiance():
    """rho = albedo / pi * max(0, n.w_i): the estimate converges to albedo / pi * E_SH(n) (Ramamoorthi-Hanrahan)."""
    env = _band_limited_map()
    coeffs = envmap.sh_project(env, degree=2)
    g = torch.Generator().manual_seed(0)
    P = 40
    normals = torch.randn(P, 3, generator=g, dtype=DT)
    normals = normals / normals.norm(dim=-1, keepdim=True)
    albedo = torch.rand(P, 3, generator=g, dtype=DT)

    def lambert(a, n, wo, wi):
        return (a / math.pi)[:, None, :] * (n @ wi.T).clamp(min=0)[..., None]

    smp = envmap.sample(envmap.importance_sampler(env), 8192, method="random", seed=5)
    wo = torch.tensor([[0.0, 0.0, 1.0]], dtype=DT).expand(P, 3)
    est = shade_pixels(lambert, [albedo, normals], wo, smp)
    expect = albedo / math.pi * envmap.sh_irradiance(coeffs, normals)
    per_sample = lambert(albedo, normals, wo, smp.dirs) * (smp.radiance / smp.pdf[:, None])
    se = per_sample.std(1) / math.sqrt(8192)
    assert ((est - expect).abs() < 4 * se + 1e-3 * expect).all()
    # a Sobol sample set of the same size is much closer
    sob = shade_pixels(lambert, [albedo, normals], wo, envmap.sample(envmap.importance_sampler(env), 8192))
    assert (sob - expect).abs().max() < 0.5 * (est - expect).abs().max() + 1e-3


def test_cosine_decoder_closed_form_base_matches_monte_carlo():
    """shading.diffuse: sh -- Monte Carlo of the MLP residual + lambert_sh's closed-form Lambertian base -- gives
    the same image as Monte Carlo of the whole cosine decoder (exact for a band-limited map), with no noise in
    the base: at 16 samples the split image is far closer to the converged one than the plain estimate."""
    torch.manual_seed(0)
    means, quats, scales, op, c2w, K = _scene()
    feats = torch.cat([torch.randn(3, 3, dtype=DT), torch.rand(3, 3, dtype=DT) * 0.3, torch.randn(3, 2, dtype=DT)], -1)
    maps, alpha, _ = rasterize(means, quats, scales, op, feats, c2w, K, 16, 16)
    dec = NeuralDecoder(8, width=16, depth=2, cosine=True).double().requires_grad_(False)
    torch.nn.init.constant_(dec.out.bias, -4.0)  # a residual of ~10% of the base
    env = _band_limited_map()
    sampler = envmap.importance_sampler(env)
    reference = deferred_shade(dec, [maps], alpha, c2w, K, envmap.sample(sampler, 16384))
    coeffs = envmap.sh_project(env, degree=2)

    def split(spp, method="random"):
        smp = envmap.sample(sampler, spp, method=method, seed=3)
        return deferred_shade(dec.residual, [maps], alpha, c2w, K, smp) + lambert_sh(maps, alpha, coeffs)

    fg = alpha[..., 0] > 1e-3
    assert torch.allclose(split(16384, "sobol")[fg], reference[fg], rtol=2e-3, atol=1e-6)
    plain16 = deferred_shade(dec, [maps], alpha, c2w, K, envmap.sample(sampler, 16, method="random", seed=3))
    err = lambda x: (x[fg] - reference[fg]).abs().mean()  # noqa: E731
    assert err(split(16)) < 0.25 * err(plain16)
    assert (lambert_sh(maps, alpha, coeffs)[~fg] == 0).all()


def test_attenuating_decoder_can_darken_its_base_and_splits_exactly():
    """shading.decoder_attenuation: the output is (d (1 - sigmoid(t)) + softplus(r)) max(0, n.w_i) >= 0; the residual
    used with the closed-form base is exactly the output minus d max(0, n.w_i) (so the sh split is unchanged), and
    unlike the residual-only decoder it can go below the Lambertian base (down to 0: full shadow)."""
    g = torch.Generator().manual_seed(0)
    P, K = 40, 30
    unit = lambda x: x / x.norm(dim=-1, keepdim=True)  # noqa: E731
    feats = torch.cat(
        [
            unit(torch.randn(P, 3, generator=g, dtype=DT)),
            torch.rand(P, 3, generator=g, dtype=DT),
            torch.randn(P, 2, generator=g, dtype=DT),
        ],
        -1,
    )
    wo, wi = unit(torch.randn(P, 3, generator=g, dtype=DT)), unit(torch.randn(K, 3, generator=g, dtype=DT))
    dec = NeuralDecoder(8, width=16, depth=2, cosine=True, attenuation=True).double().requires_grad_(False)
    assert dec.out.out_features == 6
    cos = (feats[:, :3] @ wi.T).clamp_min(0.0)[..., None]
    base = feats[:, None, 3:6] * cos
    full = dec(feats, wo, wi).double()  # the cosine decoder computes its output in float32
    assert full.shape == (P, K, 3) and (full >= 0).all()
    assert torch.allclose(dec.residual(feats, wo, wi).double() + base, full, atol=1e-6)
    torch.nn.init.constant_(dec.out.bias, 0.0)
    torch.nn.init.zeros_(dec.out.weight)  # r = t = 0: d (1 - 1/2) + log 2
    assert torch.allclose(dec(feats, wo, wi).double(), (0.5 * feats[:, None, 3:6] + math.log(2.0)) * cos, atol=1e-6)
    torch.nn.init.constant_(dec.out.bias[:3], -30.0)
    torch.nn.init.constant_(dec.out.bias[3:], 30.0)  # no residual, the base fully attenuated
    assert dec(feats, wo, wi).abs().max() < 1e-9 < base.max()
    with pytest.raises(ValueError, match="cosine"):
        NeuralDecoder(8, width=16, depth=2, cosine=False, attenuation=True)


@pytest.mark.parametrize("attenuation", [False, True])
@pytest.mark.parametrize("with_diffuse", [False, True])
def test_cosine_decoder_runs_its_mlp_on_lit_pairs_only(attenuation, with_diffuse):
    """A cosine decoder's output is 0 below the horizon of its normal, so it decodes only the pairs with n . w_i > 0
    (gathered, then scattered back): values and gradients equal the dense broadcast reference's; a pixel with a zero
    normal and a sample set entirely below every horizon give zeros, not errors."""
    g = torch.Generator().manual_seed(1)
    P, K = 50, 23
    unit = lambda x: x / x.norm(dim=-1, keepdim=True)  # noqa: E731
    feats = torch.randn(P, 8, generator=g, dtype=DT)
    feats[7, :3] = 0.0  # no normal: nothing lit
    wo, wi = unit(torch.randn(P, 3, generator=g, dtype=DT)), unit(torch.randn(K, 3, generator=g, dtype=DT))
    dec = NeuralDecoder(8, width=16, depth=3, cosine=True, attenuation=attenuation).double()
    feats.requires_grad_(True)
    lit = dec._reflectance(feats, wo, wi, with_diffuse)
    ref = dec._reflectance_dense(feats, wo, wi, with_diffuse)
    assert lit.shape == ref.shape == (P, K, 3)
    assert torch.equal(lit, ref)
    assert (lit[7] == 0).all() and ((feats[:, :3] @ wi.T <= 0)[..., None] <= (lit == 0)).all()
    w = torch.randn(P, K, 3, generator=g, dtype=DT)
    params = [feats, *dec.parameters()]
    grads = zip(torch.autograd.grad((lit * w).sum(), params), torch.autograd.grad((ref * w).sum(), params))
    (g_lit, g_ref), *rest = grads
    # at the zero normal the reference's clamp lets 1/eps through normalize (~1e6); the lit pairs leave it at 0
    assert (g_lit[7, :3] == 0).all() and g_ref[7, :3].abs().max() > 1e3
    g_lit[7, :3] = g_ref[7, :3] = 0
    for a, b in [(g_lit, g_ref), *rest]:
        assert torch.allclose(a, b, atol=1e-5, rtol=1e-4)
    dark = dec._reflectance(feats, wo, -unit(feats[:1, :3].detach()).expand(3, 3).contiguous(), with_diffuse)
    assert dark.shape == (P, 3, 3) and (dark[0] == 0).all()


def test_ggx_lobes_split():
    """ggx_reflectance = its specular lobe + ggx_diffuse_brdf x max(0, n.w_i) (the closed-form shading's split)."""
    g = torch.Generator().manual_seed(1)
    P, K = 30, 50
    unit = lambda x: x / x.norm(dim=-1, keepdim=True)  # noqa: E731
    n, wo, wi = (unit(torch.randn(m, 3, generator=g, dtype=DT)) for m in (P, P, K))
    albedo, rough, metal = (torch.rand(P, c, generator=g, dtype=DT) for c in (3, 1, 1))
    full = ggx_reflectance(albedo, rough, metal, n, wo, wi)
    spec = ggx_reflectance(albedo, rough, metal, n, wo, wi, diffuse=False)
    nl = (n @ wi.T)[..., None]
    diff = ggx_diffuse_brdf(albedo, metal, n, wo)[:, None, :] * nl.clamp_min(1e-6) * (nl > 0)
    assert torch.allclose(full, spec + diff, atol=1e-12)


def _furnace_quadrature(H=256):
    """Pixel-grid quadrature over the sphere disguised as a sample set: pdf = 1 / (K Omega) so that the
    estimator's mean equals sum f L Omega."""
    d = envmap.pixel_directions(H, 2 * H, dtype=DT).reshape(-1, 3)
    om = envmap.pixel_solid_angles(H, 2 * H).reshape(-1)
    return envmap.EnvSamples(dirs=d, pdf=1.0 / (om * d.shape[0]), radiance=torch.ones_like(d))


def test_ggx_white_furnace():
    q = _furnace_quadrature()
    n = torch.tensor([0.0, 0.0, 1.0], dtype=DT)
    angles = torch.tensor([0.0, 30.0, 60.0, 80.0], dtype=DT) * math.pi / 180
    wo = torch.stack([torch.sin(angles), torch.zeros_like(angles), torch.cos(angles)], -1)
    P = len(angles)
    ones = torch.ones(P, 3, dtype=DT)
    normal_incidence = []
    for rough in [0.3, 0.5, 0.8, 1.0]:
        r = torch.full((P, 1), rough, dtype=DT)
        metal = shade_pixels(ggx_reflectance, [ones, r, torch.ones(P, 1, dtype=DT), n.expand(P, 3)], wo, q, chunk=1)
        diel = shade_pixels(ggx_reflectance, [ones, r, torch.zeros(P, 1, dtype=DT), n.expand(P, 3)], wo, q, chunk=1)
        # energy conservation: a white furnace never reflects more than it receives
        assert (metal <= 1.0 + 5e-3).all() and (diel <= 1.0 + 5e-3).all(), (rough, metal, diel)
        normal_incidence.append(metal[0, 0].item())
        assert (diel[:2] > 0.85).all(), (rough, diel)
    # single-scattering GGX: (almost) lossless when smooth, losing more energy the rougher it gets
    assert normal_incidence[0] > 0.97
    assert all(a > b for a, b in zip(normal_incidence, normal_incidence[1:]))
    # closed form at roughness 1 (alpha = 1: D = 1/pi, G1(c) = 2c / (1 + c)), normal incidence: 1 - ln 2
    assert abs(normal_incidence[-1] - (1 - math.log(2))) < 2e-3
    # metal with albedo 0.5: Schlick F0 = 0.5 scales the lobe (near normal incidence ~ 0.5 x furnace value)
    half = shade_pixels(
        ggx_reflectance,
        [0.5 * ones[:1], torch.full((1, 1), 0.3, dtype=DT), torch.ones(1, 1, dtype=DT), n[None]],
        wo[:1],
        q,
    )
    assert 0.45 < half.mean() < 0.53


def test_ggx_ndf_is_normalised():
    q = _furnace_quadrature()
    h = q.dirs
    om = 1.0 / (q.pdf * h.shape[0])
    for rough in [0.3, 0.6, 1.0]:
        a2 = rough**4
        nh = h[:, 2].clamp(min=0)
        D = a2 / (math.pi * (nh * nh * (a2 - 1) + 1) ** 2)
        assert abs((D * nh * om).sum().item() - 1.0) < 2e-3


def test_grad_split_value_and_gradient():
    torch.manual_seed(0)
    dec = NeuralDecoder(6, width=16, depth=2, dir_freqs=2).double()
    feats = torch.randn(10, 6, dtype=DT, requires_grad=True)
    wo = torch.nn.functional.normalize(torch.randn(10, 3, dtype=DT), dim=-1)
    smp = envmap.sample(envmap.importance_sampler(_band_limited_map(16)), 64)
    full = shade_pixels(dec, [feats], wo, smp)  # all 64 with gradients
    split = shade_pixels(dec, [feats], wo, smp, spp_grad=24)
    assert torch.allclose(split, full, rtol=1e-12)  # value: the 64-sample estimate
    g_split = torch.autograd.grad(split.sum(), feats)[0]
    first24 = envmap.EnvSamples(*(t[:24] for t in smp))
    g_24 = torch.autograd.grad(shade_pixels(dec, [feats], wo, first24).sum(), feats)[0]
    assert torch.allclose(g_split, g_24, rtol=1e-10)  # gradient: the 24-sample estimate's
    assert (dec(feats, wo, smp.dirs) >= 0).all()
    with torch.no_grad():  # inference: no split
        assert torch.allclose(shade_pixels(dec, [feats], wo, smp, spp_grad=24), full)


def test_shading_config_from_config():
    cfg = config_section({"shading": {"spp_train": 64, "spp_grad": 24, "decoder_width": 256}}, "shading")
    assert (cfg.spp_train, cfg.spp_grad, cfg.decoder_width, cfg.spp_infer) == (
        64,
        24,
        256,
        ShadingConfig.from_dict({}).spp_infer,
    )


def random_ggx_pixels(P: int, seed: int, dtype=DT) -> tuple[torch.Tensor, list[torch.Tensor]]:
    """P random pixels for :func:`ggx_reflectance`: view directions wo (P, 3) in the upper hemisphere and the
    parameter maps [albedo (P, 3), roughness (P, 1), metallic (P, 1), normal (P, 3)]."""
    g = torch.Generator().manual_seed(seed)
    up = torch.tensor([0, 0, 0.5], dtype=dtype)
    wo = torch.nn.functional.normalize(torch.rand(P, 3, generator=g, dtype=dtype) + up, dim=-1)
    params = [
        torch.rand(P, 3, generator=g, dtype=dtype),
        torch.rand(P, 1, generator=g, dtype=dtype) * 0.9 + 0.1,
        torch.rand(P, 1, generator=g, dtype=dtype),
        torch.nn.functional.normalize(torch.randn(P, 3, generator=g, dtype=dtype), dim=-1),
    ]
    return wo, params


def test_chunking_leaves_the_estimate_unchanged():
    """Chunk sizes only bound memory (and set the speed: on CUDA they are scaled by CUDA_CHUNK_SCALE): any chunking
    of pixels and (pixel, sample) pairs gives the same per-pixel estimate."""
    q = _furnace_quadrature(6)
    wo, params = random_ggx_pixels(37, seed=3)
    whole = shade_pixels(ggx_reflectance, params, wo, q)
    for chunk, pairs in [(1, None), (5, None), (4096, 3 * q.dirs.shape[0]), (4096, 1)]:
        assert torch.allclose(
            shade_pixels(ggx_reflectance, params, wo, q, chunk=chunk, chunk_pairs=pairs), whole, atol=1e-12
        )
