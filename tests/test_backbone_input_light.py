"""``backbone.light_cue_input: fit``: the input light's shading ratio estimated from the input pixels alone."""

import torch
from test_priors_units import TINY

from frng.priors import backbone as bb


def _sphere_pixels(env: torch.Tensor, albedo=(0.6, 0.4, 0.3), size: int = 48) -> tuple[torch.Tensor, torch.Tensor]:
    """A Lambertian sphere seen from +z under ``env``: pixel inputs (1, 1, H, W, 7) as pixel_inputs makes them
    (gamma-2.2 colour, alpha, world normal) and the normals (1, 1, H, W, 3)."""
    from frng.envmap import sh_irradiance, sh_project

    y, x = torch.meshgrid(torch.linspace(-1, 1, size), torch.linspace(-1, 1, size), indexing="ij")
    r2 = x**2 + y**2
    inside = r2 < 0.95
    n = torch.stack([x, -y, (1 - r2).clamp_min(0).sqrt()], -1) * inside[..., None]
    e = sh_irradiance(sh_project(env), n.double()).float() / torch.pi
    col = (torch.tensor(albedo) * e).clamp(0, 1) ** (1 / 2.2) * inside[..., None]
    px = torch.cat([col, inside[..., None].float(), n], -1)[None, None]
    return px, n[None, None]


def test_fit_recovers_the_input_lights_ratio():
    """A Lambertian sphere under a sky-like light: the ratio fitted from its pixels (albedo unknown) matches the
    ratio the known map gives, within 0.05 in log on the visible hemisphere; a uniform light gives ratio ~1."""
    env = torch.ones(32, 64, 3) * 0.2
    env[:10] = torch.tensor([1.5, 1.2, 0.9])  # bright top
    px, n = _sphere_pixels(env)
    fit = bb.RelitLRMBackbone.input_light_ratio(px)
    true = bb.RelitLRMBackbone.light_ratio(env[None], n)
    m = px[..., 3] > 0.5
    assert fit.shape == true.shape == (1, 1, 48, 48, 3)
    assert (fit - true)[m].abs().mean() < 0.05, float((fit - true)[m].abs().mean())
    assert float(true[m].std()) > 0.15  # the light is far from uniform: the check is not trivial
    flat, _ = _sphere_pixels(torch.ones(32, 64, 3) * 0.5)
    assert bb.RelitLRMBackbone.input_light_ratio(flat)[m].abs().max() < 0.05


def test_fit_cue_is_target_over_input():
    """With ``fit`` the cue the SH head sees is log r_target - log r_input: relighting under the input light
    itself is (nearly) the identity, while the ``uniform`` cue would brighten the lit side a second time."""
    env = torch.ones(32, 64, 3) * 0.2
    env[:10] = 1.5
    px, n = _sphere_pixels(env)
    r_t = bb.RelitLRMBackbone.light_ratio(env[None], n)
    cue = r_t - bb.RelitLRMBackbone.input_light_ratio(px)
    m = px[..., 3] > 0.5
    assert cue[m].abs().mean() < 0.05 < r_t[m].abs().mean()


def test_models_saved_before_the_key_keep_their_behaviour(tmp_path):
    """A backbone model.pt saved before ``light_cue_input`` existed was trained with the uniform assumption: it
    loads as ``uniform`` (not today's default ``fit``); a new model records its own value."""
    from frng.priors import load_backbone

    m = bb.build(dict(TINY))
    assert m.cfg.light_cue_input == "fit"
    cfg = m.cfg.to_dict()
    old = {k: v for k, v in cfg.items() if k != "light_cue_input"}
    torch.save({"kind": "relitlrm", "config": old, "state_dict": m.state_dict()}, tmp_path / "old.pt")
    torch.save({"kind": "relitlrm", "config": cfg, "state_dict": m.state_dict()}, tmp_path / "new.pt")
    assert load_backbone(tmp_path / "old.pt").cfg.light_cue_input == "uniform"
    assert load_backbone(tmp_path / "new.pt").cfg.light_cue_input == "fit"
