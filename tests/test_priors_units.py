"""Unit tests of the priors that need no curated data: frozen loading, DiffusionRenderer adapter, SH, IDM, DDIM."""

import dataclasses
import math

import numpy as np
import pytest
import torch

from frng import camera, io
from frng.priors import BACKBONES, IDMS, build_idm, load_backbone
from frng.priors import backbone as bb
from frng.priors.diffusion_renderer import DiffusionRendererError, read_priors
from frng.priors.idm import IDMConfig, LearnedIDM, idm_loss
from frng.render.sh import eval_sh

TINY = {
    "width": 32,
    "heads": 2,
    "geo_depth": 1,
    "app_depth": 1,
    "env_height": 8,
    "sh_degree": 1,
    "den_views": 2,
    "patch": 8,
}


def _rig(V=3, H=16):
    c2w = torch.stack(
        [
            torch.tensor(camera.look_at(camera.spherical_to_cartesian(a, 15, 2.6)), dtype=torch.float32)
            for a in np.linspace(0, 360, V, endpoint=False)
        ]
    )
    intr = torch.tensor(camera.intrinsics_from_fov(50, H, H), dtype=torch.float32).expand(V, 4).clone()
    return c2w, intr


@pytest.fixture(scope="module")
def tiny_backbone_file(tmp_path_factory):
    torch.manual_seed(0)
    m = bb.build(TINY)
    path = tmp_path_factory.mktemp("bb") / "model.pt"
    io.save_torch({"kind": "relitlrm", "config": m.cfg.to_dict(), "state_dict": m.state_dict(), "steps": 0}, path)
    return path


def test_registry_names():
    assert "relitlrm" in BACKBONES
    assert {"learned", "oracle", "diffusion-renderer"} <= set(IDMS)
    with pytest.raises(KeyError, match="unknown IDM kind"):
        build_idm(None, None, "unused", kind="nope")


def test_frozen_backbone_cannot_be_updated(tiny_backbone_file):
    model = load_backbone(tiny_backbone_file)
    before = {k: v.clone() for k, v in model.state_dict().items()}
    assert not model.training and all(not p.requires_grad for p in model.parameters())
    # F-RNG-side code: a trainable head on top of the frozen tokens, optimiser over EVERYTHING it can reach
    head = torch.nn.Linear(model.cfg.width, 3)
    parent = torch.nn.ModuleDict({"backbone": model, "head": head})
    parent.train()  # must not switch the frozen prior back to training mode
    assert not model.training
    opt = torch.optim.AdamW([p for p in parent.parameters() if p.requires_grad], lr=1.0)
    c2w, intr = _rig()
    imgs = torch.rand(1, 3, 16, 16, 3)
    t_geo, raw, _, _ = model.encode_geometry(imgs, torch.ones(1, 3, 16, 16, 1), c2w[None], intr[None])
    loss = head(t_geo).square().mean() + raw.square().mean()
    loss.backward()
    opt.step()
    assert all(p.grad is None for p in model.parameters())
    assert head.weight.grad is not None
    for k, v in model.state_dict().items():
        assert torch.equal(v, before[k]), k
    # even an optimiser handed the frozen parameters directly cannot move them (no gradients exist)
    opt2 = torch.optim.SGD(model.parameters(), lr=1.0)
    opt2.step()
    for k, v in model.state_dict().items():
        assert torch.equal(v, before[k]), k


def test_relight_variable_views_and_guidance(tiny_backbone_file):
    model = load_backbone(tiny_backbone_file)
    env_in = torch.rand(8, 16, 3)  # the input views' light (light_cue_input: known)
    for V in (2, 5):
        c2w, intr = _rig(V)
        imgs, alpha = torch.rand(V, 16, 16, 3) * 0.5, torch.ones(V, 16, 16, 1)
        out = model.relight(imgs, alpha, c2w, intr, [torch.rand(8, 16, 3)], c2w[:1], intr[:1], input_env=env_in)
        rgb, a = out[0]
        assert rgb.shape == (1, 16, 16, 3) and a.shape == (1, 16, 16, 1)
        assert torch.isfinite(rgb).all() and rgb.min() >= 0
    model.cfg = dataclasses.replace(model.cfg, guidance=3.0)  # the config is frozen
    out2 = model.relight(imgs, alpha, c2w, intr, [torch.rand(8, 16, 3)], c2w[:1], intr[:1], input_env=env_in)
    assert torch.isfinite(out2[0][0]).all()


def test_sh_degree0_and_1_match_closed_form():
    d = torch.nn.functional.normalize(torch.randn(10, 3), dim=-1)
    sh = torch.zeros(10, 4, 3)
    sh[:, 0] = 1.0
    assert torch.allclose(eval_sh(1, sh, d), torch.full((10, 3), 0.28209479177387814))
    sh = torch.zeros(10, 4, 1)
    sh[:, 2] = 1.0  # l=1, m=0 -> C1 * z
    assert torch.allclose(eval_sh(1, sh, d)[:, 0], 0.4886025119029199 * d[:, 2], atol=1e-6)


def test_learned_idm_shapes_and_loss_decreases():
    torch.manual_seed(0)
    m = LearnedIDM(
        IDMConfig.from_dict(
            {"width": 32, "heads": 2, "depth": 1, "pixel_features": 8, "patch": 8, "near": 1.0, "far": 4.5}
        )
    )
    c2w, intr = _rig(2)
    imgs, alpha = torch.rand(1, 2, 16, 16, 3), torch.ones(1, 2, 16, 16, 1)
    n = torch.nn.functional.normalize(torch.randn(1, 2, 16, 16, 3), dim=-1)
    tgt = {
        "normal": n,
        "depth": torch.full((1, 2, 16, 16, 1), 2.5),
        "albedo": torch.full((1, 2, 16, 16, 3), 0.3),
        "roughness": torch.full((1, 2, 16, 16, 1), 0.7),
        "metallic": torch.zeros(1, 2, 16, 16, 1),
        "mask": alpha,
    }
    opt = torch.optim.Adam(m.parameters(), 3e-3)
    first = None
    for _ in range(30):
        loss = idm_loss(m, m(imgs, alpha, c2w[None], intr[None]), alpha, c2w[None], tgt)["total"]
        first = first if first is not None else float(loss.detach())
        opt.zero_grad()
        loss.backward()
        opt.step()
    assert float(loss) < 0.7 * first
    pri = m.predict(imgs[0], alpha[0], c2w, intr)
    assert pri.normal.shape == (2, 16, 16, 3)
    assert torch.allclose(pri.normal.norm(dim=-1), torch.ones(2, 16, 16), atol=1e-4)


def test_idm_metallic_bce_learns_the_share_of_metal_where_l1_learns_zero():
    """idm.train.metallic_loss: a metallic logit fitted to pixels of which 20 % are metal goes to L1's minimiser, the
    median (0: no metal anywhere), or to BCE's, the share of metal (0.2); an unknown name is refused."""
    cfg = {"width": 32, "heads": 2, "depth": 1, "pixel_features": 8, "patch": 8, "near": 1.0, "far": 4.5}
    m = LearnedIDM(IDMConfig.from_dict(cfg))
    c2w, _ = _rig(1)
    alpha = torch.ones(1, 1, 10, 1, 1)
    metal = (torch.arange(10) < 2).float().reshape(1, 1, 10, 1, 1)
    tgt = {
        "normal": torch.tensor([0.0, 0.0, 1.0]).expand(1, 1, 10, 1, 3),
        "depth": torch.full((1, 1, 10, 1, 1), 2.5),
        "albedo": torch.full((1, 1, 10, 1, 3), 0.3),
        "roughness": torch.full((1, 1, 10, 1, 1), 0.5),
        "metallic": metal,
        "mask": alpha,
    }
    fitted = {}
    for kind in ("l1", "bce"):
        logit = torch.zeros((), requires_grad=True)
        opt = torch.optim.Adam([logit], 0.05)
        for _ in range(400):
            raw = torch.cat([torch.zeros(1, 1, 10, 1, 8), logit.expand(1, 1, 10, 1, 1)], -1)
            loss = idm_loss(m, raw, alpha, c2w[None], tgt, kind)["metallic"]
            opt.zero_grad()
            loss.backward()
            opt.step()
        fitted[kind] = float(torch.sigmoid(logit))
    assert fitted["l1"] < 0.05 and abs(fitted["bce"] - 0.2) < 0.02, fitted
    with pytest.raises(ValueError, match="metallic_loss"):
        idm_loss(m, raw.detach(), alpha, c2w[None], tgt, "l2")


# -- DiffusionRenderer adapter on fixture files in its exact layout ---------------------------------------


def _write_dr(folder, V, H, W, normal_cam):
    folder.mkdir(parents=True, exist_ok=True)
    for f in range(V):
        base = folder / f"0000.{f:04d}"
        io.write_png(f"{base}.basecolor.png", np.full((H, W, 3), 0.5, np.float32))
        io.write_png(f"{base}.metallic.png", np.full((H, W, 3), 1.0, np.float32))
        io.write_png(f"{base}.roughness.png", np.full((H, W), 0.25, np.float32)[..., None].repeat(3, -1))
        io.write_png(f"{base}.normal.png", np.broadcast_to((normal_cam + 1) / 2, (H, W, 3)).astype(np.float32))
        io.write_png(f"{base}.depth.png", np.full((H, W, 3), 0.0, np.float32))


def test_diffusion_renderer_reader(tmp_path):
    V, H = 2, 16
    c2w, _ = _rig(V, H)
    _write_dr(tmp_path / "obj", V, 2 * H, 2 * H, np.array([0.0, 0.0, 1.0]))  # OpenGL: facing the viewer
    alpha = torch.ones(V, H, H, 1)
    pri = read_priors(tmp_path / "obj", c2w, alpha, near=1.0, far=4.0)
    assert pri.albedo.shape == (V, H, H, 3)
    assert torch.allclose(
        pri.albedo, torch.full_like(pri.albedo, float(io.srgb_decode(np.float32(128 / 255)))), atol=1e-3
    )
    assert torch.allclose(pri.metallic, torch.ones_like(pri.metallic), atol=1e-3)
    assert torch.allclose(pri.roughness, torch.full_like(pri.roughness, 64 / 255), atol=1e-3)
    assert torch.allclose(pri.depth, torch.ones_like(pri.depth))
    # a normal facing the viewer is minus the camera's optical axis in world space
    facing = -c2w[:, None, None, :3, 2].expand(V, H, H, 3)
    assert torch.allclose(pri.normal, facing, atol=0.02)


def test_diffusion_renderer_errors_name_file_and_pass(tmp_path):
    V, H = 2, 8
    c2w, _ = _rig(V, H)
    alpha = torch.ones(V, H, H, 1)
    _write_dr(tmp_path / "a", V, H, H, np.array([0.0, 0.0, 1.0]))
    (tmp_path / "a" / "0000.0001.roughness.png").unlink()
    with pytest.raises(DiffusionRendererError, match=r"0000\.0001\.roughness\.png.*'roughness'"):
        read_priors(tmp_path / "a", c2w, alpha, 1.0, 4.0)
    _write_dr(tmp_path / "b", V, H, H, np.array([0.0, 0.0, 1.0]))
    (tmp_path / "b" / "0000.0000.normal.png").write_bytes(b"not a png")
    with pytest.raises(DiffusionRendererError, match=r"0000\.0000\.normal\.png.*'normal'"):
        read_priors(tmp_path / "b", c2w, alpha, 1.0, 4.0)
    with pytest.raises(DiffusionRendererError, match="need one per input view"):
        read_priors(tmp_path / "b", *_rig(3, H)[:1], torch.ones(3, H, H, 1), 1.0, 4.0)


def test_ddim_timesteps_and_identity():
    s = bb.NoiseSchedule()
    assert s.ddim_timesteps(5) == [999, 799, 599, 399, 199]
    x0 = torch.rand(2, 3)
    assert torch.allclose(s.ddim_step(x0, x0, 999, None), x0)
    assert math.isclose(float(s.alpha_bar[0]), 1 - 0.00085, rel_tol=1e-5)


def _disc_views(V=4, H=16):
    """A sphere of radius 0.5 seen from V views at 0 deg elevation: white, its alpha from the true silhouette."""
    c2w, intr = _rig(V, H)
    o, d = camera.pixel_rays(c2w, intr, H, H)
    b = (o * d).sum(-1)
    disc = b * b - (o * o).sum(-1) + 0.25
    alpha = (disc > 0).float()[..., None]
    return torch.full((V, H, H, 3), 0.5) * alpha, alpha, c2w, intr


def test_light_ratio_is_lambertian():
    """The light cue is the Lambertian shading ratio: 1 under a uniform map, brighter towards a bright hemisphere."""
    n = torch.tensor([[0.0, 0.0, 1.0], [0.0, 0.0, -1.0], [0.0, 0.0, 0.0]]).reshape(1, 3, 1, 1, 3)
    uniform = torch.ones(1, 16, 32, 3)
    assert torch.allclose(bb.RelitLRMBackbone.light_ratio(uniform, n), torch.zeros(1, 3, 1, 1, 3), atol=1e-2)
    sky = torch.ones(1, 16, 32, 3) * 0.05
    sky[:, :8] = 2.0  # bright upper hemisphere (row 0 = +Z in frng.render.envmap's convention)
    r = bb.RelitLRMBackbone.light_ratio(sky, n).exp()
    assert r[0, 0, 0, 0, 0] > 1.5 and r[0, 1, 0, 0, 0] < 0.5  # up-facing lit, down-facing dark
    assert torch.allclose(r[0, 2], torch.ones(1, 1, 3))  # no normal: ratio 1
    assert torch.equal(bb.RelitLRMBackbone.light_ratio(None, n), torch.zeros_like(n))


def test_untrained_backbone_relights_with_light_cue():
    """With ``light_cue`` even an untrained backbone's renders follow the target light (the light-blind backbone
    gave the same colours under every light); without it they do not depend on the light through the base colour."""
    imgs, alpha, c2w, intr = _disc_views()
    top = torch.ones(32, 64, 3) * 0.05
    top[:16] = 2.0
    bottom = top.flip(0)
    means = {}
    for cue in (True, False):
        torch.manual_seed(0)
        m = bb.build(dict(TINY, light_cue=cue)).eval()
        out = m.relight(imgs, alpha, c2w, intr, [top, bottom], c2w[:1], intr[:1], input_env=torch.ones(32, 64, 3))
        H = imgs.shape[1]
        up = [float(rgb[0, : H // 2][a[0, : H // 2, :, 0] > 0.5].mean()) for rgb, a in out]
        down = [float(rgb[0, H // 2 :][a[0, H // 2 :, :, 0] > 0.5].mean()) for rgb, a in out]
        means[cue] = (up, down)
    (up, down) = means[True]
    assert up[0] / down[0] > 1.5 * up[1] / down[1]  # the upper half is brighter under the top light
    assert up[0] > 1.3 * up[1]
    (up, down) = means[False]  # the untrained light-blind head copies its input colours under every light
    assert abs(up[0] - up[1]) < 1e-6 and abs(down[0] - down[1]) < 1e-6


def test_multiview_cues_are_fp32_under_autocast():
    """The backbone's multi-view cues (``prior_raw``) are the same bytes with and without bf16 autocast: training
    (under autocast) sees the cues inference computes (in bf16 the hull normals differed by ~10 degrees)."""
    imgs, alpha, c2w, intr = _disc_views()
    torch.manual_seed(0)
    m = bb.build(TINY)
    if not m.cfg.cues:
        pytest.skip("the tiny backbone has no multi-view cues")
    args = (imgs[None], alpha[None], c2w[None], intr[None])
    plain = m.prior_raw(*args)
    with torch.autocast("cpu", dtype=torch.bfloat16):
        auto = m.prior_raw(*args)
    assert all(a.dtype == torch.float32 and torch.equal(a, b) for a, b in zip(auto, plain))
