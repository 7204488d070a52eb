"""The closed-form specular base (frng.render.prefilter): prefiltered maps, lookups, the reflected direction."""

import math

import torch

from frng import camera, envmap
from frng.render.prefilter import KAPPAS, lookup, prefilter, specular_base


def _spot(direction, H=32, power=50.0):
    """A map that is dark except for a small bright spot around ``direction``."""
    d = envmap.pixel_directions(H, 2 * H)
    c = (d @ torch.tensor(direction)).clamp(-1, 1)
    return (0.01 + power * (c > math.cos(math.radians(6))).float())[..., None].expand(H, 2 * H, 3).clone()


def test_prefilter_keeps_energy_and_blurs_more_at_lower_kappa():
    env = _spot([1.0, 0.0, 0.0])
    pref = prefilter(env)
    assert pref.shape == (len(KAPPAS), 32, 64, 3)
    omega = envmap.pixel_solid_angles(32, 64, dtype=torch.float32)[..., None]
    e_in = float((env * omega).sum())
    for lvl in pref:  # a normalised lobe moves light around, it neither makes nor loses it (within ~5%)
        assert abs(float((lvl * omega).sum()) - e_in) / e_in < 0.05
    at_spot = [
        float(lookup(pref, torch.tensor([[1.0, 0.0, 0.0]]), torch.tensor([float(i)]))[0, 0]) for i in range(len(KAPPAS))
    ]
    assert all(a > b for a, b in zip(at_spot, at_spot[1:]))  # peak falls as the lobe widens
    away = float(lookup(pref, torch.tensor([[-1.0, 0.0, 0.0]]), torch.tensor([0.0]))[0, 0])
    assert away < 0.05 * at_spot[0]


def test_prefilter_is_memoised_per_tensor_and_sees_in_place_changes():
    env = _spot([0.0, 1.0, 0.0])
    first = prefilter(env)
    assert prefilter(env) is first  # the same map again: no second convolution
    env.mul_(2.0)  # changed in place: recomputed, not the stale result
    doubled = prefilter(env)
    assert doubled is not first and torch.allclose(doubled, 2.0 * first, rtol=1e-5)
    other = env.clone()  # equal content, another tensor: computed for it (equal values)
    assert prefilter(other) is not doubled and torch.allclose(prefilter(other), doubled)
    assert prefilter(env, kappas=(50.0,)).shape == (1, 32, 64, 3)  # other lobes: another entry


def test_lookup_interpolates_levels_and_wraps_longitude():
    pref = torch.arange(4, dtype=torch.float32)[:, None, None, None].expand(4, 8, 16, 3).clone()
    v = lookup(pref, torch.tensor([[0.0, 0.0, 1.0], [-1.0, 1e-4, 0.0]]), torch.tensor([1.25, 2.5]))
    assert torch.allclose(v[:, 0], torch.tensor([1.25, 2.5]))
    ramp = torch.zeros(1, 8, 16, 3)
    ramp[:, :, 0] = 1.0
    ramp[:, :, -1] = 1.0  # the seam columns: u ~ 0 and u ~ 1 are neighbours
    seam = lookup(ramp, torch.tensor([[-1.0, 1e-6, 0.0], [-1.0, -1e-6, 0.0]]), torch.zeros(2))  # u = 0 / 1
    assert torch.allclose(seam[0], seam[1], atol=1e-3) and float(seam[0, 0]) > 0.9


def test_specular_base_shows_the_mirror_image_of_a_light():
    """A mirror-like surface facing the camera reflects the spot behind the camera and not a spot behind it."""
    cam = torch.tensor(camera.look_at(camera.spherical_to_cartesian(0, 0, 2.6)), dtype=torch.float32)[None]
    intr = torch.tensor(camera.intrinsics_from_fov(20, 4, 4), dtype=torch.float32)[None]
    _, d = camera.pixel_rays(cam, intr, 4, 4)
    eye = cam[0, :3, 3] / cam[0, :3, 3].norm()
    alpha = torch.ones(1, 4, 4, 1)
    maps = torch.zeros(1, 4, 4, 10)
    maps[..., :3] = eye  # normal towards the camera
    maps[..., 6:9] = 10.0  # k_s ~ 6
    maps[..., 9] = -10.0  # sharpest level
    lit = specular_base(maps, alpha, prefilter(_spot(eye.tolist())), d)
    dark = specular_base(maps, alpha, prefilter(_spot((-eye).tolist())), d)
    assert float(lit.mean()) > 20 * float(dark.mean())
    maps[..., 6:9] = -20.0  # k_s ~ 0: nothing
    assert float(specular_base(maps, alpha, prefilter(_spot(eye.tolist())), d).max()) < 1e-4
    # gradients reach k_s, the level and the normal
    maps = maps.clone().requires_grad_(True)
    specular_base(maps, alpha, prefilter(_spot(eye.tolist())), d).sum().backward()
    assert torch.isfinite(maps.grad).all() and maps.grad[..., 6:10].abs().sum() > 0
