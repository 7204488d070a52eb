"""``backbone.light_cue_input``: the input light's shading ratio estimated from the input pixels alone (``fit``) or
taken from the input views' map the caller gives (``known``, an oracle setting; ``fit``, the default, estimates it), and ``cue_in_head``."""

import torch
from test_priors_units import TINY

from frng.priors import backbone as bb


def _sphere_pixels(env: torch.Tensor, albedo=(0.6, 0.4, 0.3), size: int = 48) -> tuple[torch.Tensor, torch.Tensor]:
    """A Lambertian sphere seen from +z under ``env``: pixel inputs (1, 1, H, W, 7) as pixel_inputs makes them
    (gamma-2.2 colour, alpha, world normal) and the normals (1, 1, H, W, 3)."""
    from frng.render.envmap import sh_irradiance, sh_project

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


def test_models_saved_before_the_keys_keep_their_behaviour(tmp_path):
    """A backbone model.pt saved before ``light_cue_input`` and ``cue_in_head`` existed was trained with the uniform
    assumption and a head that sees the cue: it loads that way (not today's defaults ``fit`` and no cue in the
    head), and its head keeps the input width its weights have; a new model records its own values."""
    from frng.priors import load_backbone

    old_m = bb.build(dict(TINY, light_cue_input="uniform", cue_in_head=True))
    old = {k: v for k, v in old_m.cfg.to_dict().items() if k not in ("light_cue_input", "cue_in_head")}
    m = bb.build(dict(TINY))
    assert (m.cfg.light_cue_input, m.cfg.cue_in_head) == ("fit", False)
    torch.save({"kind": "relitlrm", "config": old, "state_dict": old_m.state_dict()}, tmp_path / "old.pt")
    torch.save({"kind": "relitlrm", "config": m.cfg.to_dict(), "state_dict": m.state_dict()}, tmp_path / "new.pt")
    loaded = load_backbone(tmp_path / "old.pt").cfg
    assert (loaded.light_cue_input, loaded.cue_in_head) == ("uniform", True)
    loaded = load_backbone(tmp_path / "new.pt").cfg
    assert (loaded.light_cue_input, loaded.cue_in_head) == ("fit", False)


def test_known_cue_is_target_over_the_given_input_light():
    """``known``: the pixel inputs carry the given input map's log ratio at the hull normals, and an untrained head
    (zero-initialised output: gain 0) gives back the input colours under the input light itself and relights them
    by the Lambertian ratio target / input under another light. Without the map the backbone says what it needs."""
    import pytest

    env_in = torch.ones(32, 64, 3) * 0.2
    env_in[:10] = torch.tensor([1.5, 1.2, 0.9])  # bright top
    env_t = env_in.flip(0)  # bright bottom
    px7, n = _sphere_pixels(env_in, size=16)
    m = bb.build(dict(TINY, light_cue_input="known")).eval()
    col = px7[0, 0, ..., :3] ** 2.2 * px7[0, 0, ..., 3:4]
    images, alpha, normals = col[None], px7[0, 0, ..., 3:4][None], n[0]
    px = m.pixel_inputs(images, alpha, normals, env_in)
    assert px.shape == (1, 1, 16, 16, 10)
    assert torch.allclose(px[..., 7:10], bb.RelitLRMBackbone.light_ratio(env_in[None], n))
    with pytest.raises(ValueError, match="input_env"):
        m.pixel_inputs(images, alpha, normals)
    t_app = torch.randn(1, 1, 2, 2, m.cfg.width)
    fg = px[0, 0, ..., 3] > 0.5

    @torch.no_grad()
    def base_colour(env):  # the DC term's colour in gamma space (sh = (c - 0.5) / C0 for the base)
        sh = m.sh_coefficients(t_app, px, env[None])
        return (sh[0, :, 0] * bb.C0 + 0.5).reshape(16, 16, 3)

    assert torch.allclose(base_colour(env_in)[fg], px[0, 0, ..., :3][fg], atol=1e-5)  # identity under its own light
    ratio = (bb.RelitLRMBackbone.light_ratio(env_t[None], n) - px[..., 7:10])[0, 0] / 2.2
    relit = px[0, 0, ..., :3] * ratio.exp()
    assert torch.allclose(base_colour(env_t)[fg], relit[fg], atol=1e-4)
    assert float((base_colour(env_t) - base_colour(env_in))[fg].abs().mean()) > 0.05  # the cue acts


def test_cue_in_head_sets_what_the_head_sees():
    """``cue_in_head: false`` keeps log r out of the per-pixel head's inputs (F + 4 features), true adds it (F + 7)."""
    for flag, extra in ((False, 0), (True, 3)):
        m = bb.build(dict(TINY, cue_in_head=flag))
        assert m.pixel_head[0].in_features == m.cfg.pixel_features + 4 + extra
