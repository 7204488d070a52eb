"""F-RNG's per-pixel inputs (frng.model.pixel_head.pixel_map): the albedo estimate c / E(n) behind the Lambertian start."""

import math

import torch

from frng.model.pixel_head import PIXEL_RATIO, RATIO_TRUST, pixel_map
from frng.priors.intrinsics import IntrinsicPriors
from frng.render import envmap


def _hard_light(h: int = 32) -> torch.Tensor:
    """An equirect map dark everywhere but a small bright patch: a hard studio light."""
    env = torch.full((h, 2 * h, 3), 1e-4)
    env[h // 4 : h // 4 + 3, h // 2 : h // 2 + 3] = 200.0
    return env


def _priors(normals: torch.Tensor, albedo: float) -> IntrinsicPriors:
    V, H, W, _ = normals.shape
    z = torch.zeros(V, H, W, 1)
    return IntrinsicPriors(normals, z + 2.0, torch.full((V, H, W, 3), albedo), z + 0.5, z, z + 1.0)


def test_shadowed_pixels_take_the_idm_albedo_and_lit_ones_their_colour_over_the_irradiance():
    env = _hard_light()
    # one view, 2 x 2 pixels: two normals towards the light, two away from it
    sh = envmap.sh_project(env).float()
    dirs = torch.tensor([[0.0, 0.0, 1.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
    E = envmap.sh_irradiance(sh, dirs)[:, 0]
    lit, dark = dirs[E.argmax()], dirs[E.argmin()]
    assert E.max() > 100 * E.min().clamp_min(1e-9)
    normals = torch.stack([lit, lit, dark, dark]).reshape(1, 2, 2, 3)
    colour = 0.05  # every pixel: the same dim colour (a shadow's colour is not an albedo)
    images = torch.cat([torch.full((1, 2, 2, 3), colour), torch.ones(1, 2, 2, 1)], -1)
    pm = pixel_map(images, _priors(normals, albedo=0.3), 1, normals, env)
    ratio = pm[..., PIXEL_RATIO] ** 2.2
    E_lit = float(envmap.sh_irradiance(sh, lit)[0]) / math.pi
    assert torch.allclose(ratio[0, 0], torch.full((2, 3), min(colour / E_lit, 1.0)), atol=1e-3)
    # the dark side: E far under RATIO_TRUST of the lit side's -> the IDM's albedo, not c / E clamped at its bound
    assert float(envmap.sh_irradiance(sh, dark)[0]) / math.pi < RATIO_TRUST * E_lit
    assert torch.allclose(ratio[0, 1], torch.full((2, 3), 0.3), atol=1e-3)


def test_the_estimate_is_an_albedo_without_priors_too():
    env = torch.full((16, 32, 3), 0.5)
    normals = torch.tensor([0.0, 0.0, 1.0]).expand(1, 4, 4, 3).clone()
    images = torch.cat([torch.full((1, 4, 4, 3), 0.9), torch.ones(1, 4, 4, 1)], -1)  # brighter than the light
    pm = pixel_map(images, None, 1, normals, env)
    assert float((pm[..., PIXEL_RATIO] ** 2.2).max()) <= 1.0 + 1e-5


def test_specular_start_splits_a_metals_colour_into_the_specular_base():
    """frng.specular_start: an untrained pixel head starts a metal (IDM metallic 1) with its colour pi c / E(n) as the
    specular base's colour (features 6:9) and its roughness r as the lobe's (sigmoid(4 f_9) = r), no diffuse; a
    non-metal (metallic 0) starts exactly as without it; a head without the IDM's channels refuses it."""
    import pytest

    from frng.model.pixel_head import (
        PIXEL_IDM_METALLIC,
        PIXEL_IDM_NORMAL,
        PIXEL_IDM_ROUGHNESS,
        PixelHead,
        pixel_channels,
    )

    C, P = 16, pixel_channels(True)
    g = torch.randn(2, C)
    pixel = torch.rand(2, P)
    pixel[:, PIXEL_RATIO] = torch.tensor([[0.2, 0.3, 0.8], [0.5, 0.5, 0.5]]) ** (1 / 2.2)
    pixel[:, PIXEL_IDM_METALLIC] = torch.tensor([1.0, 0.0])
    pixel[:, PIXEL_IDM_ROUGHNESS] = 0.2
    torch.manual_seed(0)
    plain = PixelHead(C, P, 8, PIXEL_IDM_NORMAL)
    torch.manual_seed(0)
    spec = PixelHead(C, P, 8, PIXEL_IDM_NORMAL, specular_start=True)
    a, b = plain(g, pixel), spec(g, pixel)
    ratio = pixel[:, PIXEL_RATIO] ** 2.2
    assert torch.equal(a[1], b[1])  # the non-metal
    assert torch.allclose(b[0, 3:6], g[0, 3:6], atol=1e-6)  # the metal diffuses nothing more than the token says
    assert torch.allclose(b[0, 6:9], g[0, 6:9] + ratio[0], atol=1e-6)
    assert torch.allclose(torch.sigmoid(4 * (b[0, 9] - g[0, 9])), torch.tensor(0.2), atol=1e-5)
    assert torch.equal(a[0, :3], b[0, :3]) and torch.equal(a[0, 10:], b[0, 10:])
    with pytest.raises(ValueError, match="specular_start"):
        PixelHead(C, pixel_channels(False), 8, 10, specular_start=True)
