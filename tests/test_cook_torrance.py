"""The no-neural ablation's Cook-Torrance path (frng.model.materialformer.decode_pbr -> frng.render.shading.ggx_shade):
whatever its parameter heads output (extreme logits, back-facing or grazing normals), a lit surface never renders
black and the gradients stay finite. Before, a normal facing away from the camera made one-sided GGX exactly zero
and the logits could reach a black base colour, a pure metal or a near-delta lobe: trained no-neural models
rendered black holes where the ground truth was lit."""

import math

import torch

from frng import camera
from frng.model.materialformer import decode_pbr
from frng.render import envmap
from frng.render.shading import (
    GGX_MAX_METALLIC,
    GGX_MIN_ALBEDO,
    GGX_MIN_COS_VIEW,
    GGX_MIN_ROUGHNESS,
    face_forward,
    ggx_reflectance,
    ggx_shade,
    smooth_normals,
)

H = W = 16


def _camera():
    """One camera at the origin looking along +z (the frng.camera convention of tests/test_render_shading.py)."""
    c2w = torch.eye(4)[None]
    K = torch.tensor([[16.0, 16.0, 8.0, 8.0]])
    return c2w, K


def _env(h=32):
    """A positive sky with a small bright sun: importance sampling concentrates on the sun, the SH on the sky."""
    d = envmap.pixel_directions(h, 2 * h)
    x, y, z = d.unbind(-1)
    sky = torch.stack([0.4 + 0.2 * z, 0.5 + 0.2 * z, 0.7 + 0.1 * x], -1).clamp_min(0.05)
    sun = torch.nn.functional.normalize(torch.tensor([0.3, -0.5, -0.8]), dim=0)
    return sky + 50.0 * (d @ sun > 0.995).float()[..., None]


def _raw(gen, scale=10.0):
    """Random head outputs (1, H, W, 8) with every extreme corner included: logits +-30 for albedo, roughness and
    metallic, normals pointing towards, away from and across the view (and a zero vector)."""
    raw = scale * torch.randn(1, H, W, 8, generator=gen)
    corners = torch.tensor([[a, r, m] for a in (-30.0, 30.0) for r in (-30.0, 30.0) for m in (-30.0, 30.0)])
    raw[0, 0, :8, 0:3] = corners[:, 0:1]
    raw[0, 0, :8, 3], raw[0, 0, :8, 4] = corners[:, 1], corners[:, 2]
    raw[0, 1, :8, 0:5] = corners.repeat_interleave(torch.tensor([3, 1, 1]), 1)  # same corners, other normals
    raw[0, 2, 0, 5:8] = 0.0  # zero normal
    return raw


def _maps(raw):
    p = decode_pbr(raw)
    return torch.cat([p["albedo"], p["roughness"], p["metallic"], p["normal"]], -1)


def test_decode_pbr_ranges():
    raw = torch.tensor([[-1e4] * 8, [1e4] * 8, [0.0] * 8])
    p = decode_pbr(raw)
    assert torch.allclose(p["albedo"][0], torch.full((3,), GGX_MIN_ALBEDO)) and (p["albedo"] <= 1).all()
    assert torch.isclose(p["roughness"][0, 0], torch.tensor(GGX_MIN_ROUGHNESS)) and GGX_MIN_ROUGHNESS >= 0.08
    assert torch.isclose(p["metallic"][1, 0], torch.tensor(GGX_MAX_METALLIC)) and GGX_MAX_METALLIC < 1
    assert torch.allclose(p["normal"].norm(dim=-1), torch.ones(3))


def test_face_forward():
    g = torch.Generator().manual_seed(0)
    n = torch.randn(500, 3, generator=g)
    wo = torch.nn.functional.normalize(torch.randn(500, 3, generator=g), dim=-1)
    f = face_forward(n, wo)
    assert torch.allclose(f.norm(dim=-1), torch.ones(500), atol=1e-5)
    assert ((f * wo).sum(-1) >= 0.9 * GGX_MIN_COS_VIEW).all()
    unit = torch.nn.functional.normalize(n, dim=-1)
    front = (unit * wo).sum(-1) >= GGX_MIN_COS_VIEW  # camera-facing normals are left alone
    assert torch.allclose(f[front], unit[front], atol=1e-6)
    back = (unit * wo).sum(-1) <= -GGX_MIN_COS_VIEW  # clearly back-facing ones are flipped
    assert torch.allclose(f[back], -unit[back], atol=1e-6)
    assert torch.isfinite(face_forward(torch.zeros(2, 3), wo[:2])).all()


def test_lit_surface_never_renders_black():
    """(a) For random and extreme head outputs, every pixel whose Lambertian irradiance E (at the camera-facing
    normal it is shaded with) is above a threshold gets radiance >= 1e-3 E / pi -- the bound of the darkest
    allowed material (base colour 0.03, metallic 0.9, grazing view: (1 - F) (1 - m) a ~ 1.2e-3) -- in both diffuse
    modes; one-sided GGX (the old path) is exactly 0 on the back-facing normals."""
    c2w, K = _camera()
    env = _env()
    sh = envmap.sh_project(env).float()
    samples = envmap.sample(envmap.importance_sampler(env), 64, seed=1)
    _, d = camera.pixel_rays(c2w, K, H, W)
    wo = -d.reshape(-1, 3)
    alpha = torch.ones(1, H, W, 1)
    for seed in range(3):
        raw = _raw(torch.Generator().manual_seed(seed))
        maps = _maps(raw)
        n = face_forward(maps[0, ..., 5:8].reshape(-1, 3), wo)
        E = envmap.sh_irradiance(sh, n).clamp_min(0.0).min(-1).values  # (P,)
        lit = E > 0.05 * E.max()
        assert lit.float().mean() > 0.5
        for mode in ("sh", "mc"):
            rgb = ggx_shade(maps, alpha, c2w, K, env, samples, diffuse=mode).reshape(-1, 3)
            assert torch.isfinite(rgb).all() and (rgb >= 0).all()
            ratio = rgb.min(-1).values / (E / math.pi)
            assert (ratio[lit] > 1e-3).all(), (mode, seed, float(ratio[lit].min()))
            # a material in the middle of the ranges (logits within +-3) stays well away from black
            mid = (raw[0, ..., 0:5].abs() < 3).all(-1).reshape(-1) & lit
            if mid.any():
                assert (ratio[mid] > 0.02).all(), (mode, seed, float(ratio[mid].min()))
        # the old one-sided path: zero wherever the raw normal faces away from the camera
        p = decode_pbr(raw.reshape(-1, 8))
        old = ggx_reflectance(p["albedo"], p["roughness"], p["metallic"], p["normal"], wo, samples.dirs)
        away = (p["normal"] * wo).sum(-1) < 0
        assert away.any() and (old[away] == 0).all()


def test_gradients_finite():
    """(b) Gradients w.r.t. the raw head outputs are finite for extreme logits, zero / grazing / back-facing
    normals, in both diffuse modes, with the training's spp_grad split."""
    c2w, K = _camera()
    env = _env()
    samples = envmap.sample(envmap.importance_sampler(env), 32, seed=2)
    _, d = camera.pixel_rays(c2w, K, H, W)
    alpha = torch.rand(1, H, W, 1, generator=torch.Generator().manual_seed(5)).clamp_min(0.01)
    alpha[0, 3, 3] = 0.0  # background pixel
    for seed in range(2):
        raw = _raw(torch.Generator().manual_seed(10 + seed), scale=30.0)
        raw[0, 4, :, 5:8] = torch.cross(d[0, 4], torch.tensor([[0.0, 1.0, 0.0]]).expand(W, 3), dim=-1)  # grazing
        raw[0, 5, :, 5:8] = d[0, 5]  # exactly back-facing
        raw.requires_grad_(True)
        for mode in ("sh", "mc"):
            rgb = ggx_shade(_maps(raw) * alpha, alpha, c2w, K, env, samples, spp_grad=16, diffuse=mode)
            (g,) = torch.autograd.grad((rgb**2).sum() + rgb.sum(), raw)
            assert torch.isfinite(rgb).all() and torch.isfinite(g).all(), mode
            assert g.abs().sum() > 0


def _striped_maps(width: int = 2, tilt_deg: float = 70.0):
    """A camera-facing plane (alpha 1, grey albedo, rough dielectric) whose normals alternate in vertical stripes
    ``width`` px wide between -z tilted by +-tilt_deg about y: the pattern where two input views' Gaussians
    interleave at a new view, each with its own view's normal. The mean of the two normals is the plane's, -z."""
    t = math.radians(tilt_deg)
    a, b = torch.tensor([math.sin(t), 0.0, -math.cos(t)]), torch.tensor([-math.sin(t), 0.0, -math.cos(t)])
    cols = (torch.arange(W) // width) % 2 == 0
    n = torch.where(cols[None, :, None], a, b).expand(H, W, 3)
    rest = torch.tensor([0.5, 0.5, 0.5, 0.8, 0.0])  # albedo, roughness, metallic
    return torch.cat([rest.expand(H, W, 5), n], -1)[None], torch.ones(1, H, W, 1)


def test_smooth_normals_keeps_constant_normals_and_other_channels():
    g = torch.Generator().manual_seed(3)
    maps = torch.rand(2, H, W, 8, generator=g)
    alpha = torch.rand(2, H, W, 1, generator=g).clamp_min(0.05)
    n = torch.nn.functional.normalize(torch.tensor([0.2, -0.3, -1.0]), dim=0) * 0.7  # length 0.7 kept
    maps = torch.cat([maps[..., :5], n.expand(2, H, W, 3)], -1) * alpha
    out = smooth_normals(maps, alpha, slice(5, 8), 2.0)
    assert out.shape == maps.shape
    assert torch.equal(out[..., :5], maps[..., :5])
    assert torch.allclose(out, maps, atol=1e-5)
    assert smooth_normals(maps, alpha, slice(5, 8), 0.0) is maps


def test_striped_normals_shade_without_dark_stripes():
    """(c) Interleaved normals of two views (:func:`_striped_maps`): lit by a sun on one side, every second stripe
    faces away from it and renders much darker than its neighbour -- the dark stripes and patches of the
    trained no-neural ablation on the default tier. After :func:`smooth_normals` (what FRNG.shade does with
    ``shading.normal_blur``) the plane renders nearly uniform, as its ground truth would."""
    c2w, K = _camera()
    env = _env()
    samples = envmap.sample(envmap.importance_sampler(env), 64, seed=1)
    maps, alpha = _striped_maps()
    inner = (slice(None), slice(4, H - 4), slice(4, W - 4))
    raw = ggx_shade(maps, alpha, c2w, K, env, samples)[inner].mean(-1)
    assert raw.max() / raw.min() > 1.5  # the premise: stripes
    smooth = ggx_shade(smooth_normals(maps, alpha, slice(5, 8), 2.0), alpha, c2w, K, env, samples)[inner].mean(-1)
    assert smooth.max() / smooth.min() < 1.1, float(smooth.max() / smooth.min())
    assert smooth.min() > raw.min()
