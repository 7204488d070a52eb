"""Environment-light importance sampling and SH projection (frng.render.envmap): pdfs normalised, samples follow the
pmf, estimates unbiased within Monte-Carlo error (4 standard errors), SH round trip."""

import math

import pytest
import torch

from frng.render import envmap
from frng.render.sh import eval_sh, sh_basis


def _map(H=32, seed=0):
    g = torch.Generator().manual_seed(seed)
    img = torch.rand(H, 2 * H, 3, generator=g, dtype=torch.float64) ** 4 * 3.0
    img[3, 7] = torch.tensor([200.0, 150.0, 100.0], dtype=torch.float64)  # a sun
    img[H - max(1, H // 8) :, :] = 0.0  # black ground
    return img


def test_pdf_integrates_to_one_and_matches_sample_pdf():
    img = _map()
    s = envmap.importance_sampler(img)
    H, W = img.shape[:2]
    d = envmap.pixel_directions(H, W, dtype=torch.float64)
    total = (envmap.pdf(s, d) * envmap.pixel_solid_angles(H, W)).sum()
    assert abs(total.item() - 1.0) < 1e-10
    # Monte-Carlo over uniform directions: E[pdf * 4 pi] = 1
    g = torch.Generator().manual_seed(1)
    u = torch.randn(200_000, 3, generator=g, dtype=torch.float64)
    u = u / u.norm(dim=-1, keepdim=True)
    vals = envmap.pdf(s, u) * 4 * math.pi
    assert abs(vals.mean().item() - 1.0) < 4 * vals.std().item() / math.sqrt(len(vals))
    for method in ["random", "stratified", "sobol"]:
        smp = envmap.sample(s, 1000, method=method, seed=3)
        assert torch.allclose(smp.dirs.norm(dim=-1), torch.ones(1000, dtype=torch.float64))
        assert torch.allclose(smp.pdf, envmap.pdf(s, smp.dirs), rtol=1e-12)
        assert torch.allclose(smp.radiance, envmap.lookup(s.image, smp.dirs))


def test_samples_follow_the_pmf():
    img = _map(H=8)
    s = envmap.importance_sampler(img)
    n = 400_000
    smp = envmap.sample(s, n, method="random", seed=2)
    u, v = envmap.dir_to_uv(smp.dirs)
    idx = (v * 8).long().clamp(0, 7) * 16 + (u * 16).long().clamp(0, 15)
    freq = torch.bincount(idx, minlength=128).double() / n
    p = s.pmf.reshape(-1)
    z = (freq - p) / torch.sqrt(p * (1 - p) / n)
    assert z.abs().max() < 5.0
    # inside a pixel the points are uniform in solid angle: z = cos(polar) uniform over the band
    sun = idx == 3 * 16 + 7
    assert sun.sum() > 0.5 * n
    z_sun = smp.dirs[sun, 2]
    c0, c1 = math.cos(math.pi * 3 / 8), math.cos(math.pi * 4 / 8)
    assert z_sun.min() >= c1 - 1e-12 and z_sun.max() <= c0 + 1e-12
    assert abs(z_sun.mean().item() - (c0 + c1) / 2) < 4 * (c0 - c1) / math.sqrt(12 * sun.sum().item())


def test_constant_map_integrates_to_4pi_L_for_every_sample():
    L = torch.tensor([0.5, 1.0, 2.0], dtype=torch.float64)
    img = L.expand(16, 32, 3).clone()
    s = envmap.importance_sampler(img)
    for method in ["random", "stratified", "sobol"]:
        smp = envmap.sample(s, 64, method=method)
        est = smp.radiance / smp.pdf[:, None]
        assert torch.allclose(est, (4 * math.pi * L).expand(64, 3), rtol=1e-10)


@pytest.mark.parametrize("method", ["random", "stratified", "sobol"])
def test_estimator_unbiased_on_a_high_dynamic_range_map(method):
    img = _map()
    exact = (img * envmap.pixel_solid_angles(32, 64)[..., None]).sum((0, 1))
    s = envmap.importance_sampler(img)
    # integrand with a cosine lobe: int L(w) max(0, n.w) dw (not proportional to the pdf)
    n = torch.tensor([0.3, -0.5, 0.81], dtype=torch.float64)
    n = n / n.norm()
    d = envmap.pixel_directions(32, 64, dtype=torch.float64)
    exact_cos = (img * ((d @ n).clamp(min=0) * envmap.pixel_solid_angles(32, 64))[..., None]).sum((0, 1))
    smp = envmap.sample(s, 8192, method=method, seed=11)
    est = smp.radiance / smp.pdf[:, None]
    est_cos = est * (smp.dirs @ n).clamp(min=0)[:, None]
    for e, ex in [(est, exact), (est_cos, exact_cos)]:
        se = e.std(0) / math.sqrt(e.shape[0])
        assert ((e.mean(0) - ex).abs() < 4 * se + 1e-9).all(), (e.mean(0), ex, se)


def test_low_discrepancy_reduces_error():
    img = _map(seed=4)
    s = envmap.importance_sampler(img)
    n = torch.tensor([0.0, 0.6, 0.8], dtype=torch.float64)
    d = envmap.pixel_directions(32, 64, dtype=torch.float64)
    exact = (img[..., 1] * (d @ n).clamp(min=0) * envmap.pixel_solid_angles(32, 64)).sum()

    def rmse(method):
        errs = []
        for seed in range(24):
            smp = envmap.sample(s, 256, method=method, seed=seed)
            errs.append((smp.radiance[:, 1] / smp.pdf * (smp.dirs @ n).clamp(min=0)).mean() - exact)
        return torch.stack(errs).pow(2).mean().sqrt()

    assert rmse("sobol") < rmse("random")
    assert rmse("stratified") < rmse("random")


def test_sh_projection_round_trip():
    g = torch.Generator().manual_seed(0)
    coeffs = torch.randn(16, 3, generator=g, dtype=torch.float64)
    H, W = 128, 256
    d = envmap.pixel_directions(H, W, dtype=torch.float64)
    img = eval_sh(3, coeffs, d)
    back = envmap.sh_project(img, degree=3)
    assert torch.allclose(back, coeffs, atol=2e-3)
    assert sh_basis(3, d).shape == (H, W, 16)
