"""Frontal view selection (frng.priors.viewselect): of two views' per-pixel Gaussians on the same plane, the oblique
view's are dominated where the frontal view covers the plane, kept where it does not; the frontal view's are kept."""

import torch

from frng import camera
from frng.priors.surfels import grid_normals
from frng.priors.viewselect import dominated


def _rig(elevations, azimuths, size=32, half=0.5):
    """Cameras on the plane z = 0 (the square |x|, |y| <= half) and per-pixel Gaussians where their rays hit it."""
    c2ws, means, keeps = [], [], []
    intr = torch.tensor(camera.intrinsics_from_fov(40.0, size, size), dtype=torch.float32)[None]
    for el, az in zip(elevations, azimuths):
        c2w = torch.tensor(camera.look_at(camera.spherical_to_cartesian(az, el, 2.5)), dtype=torch.float32)[None]
        o, d = camera.pixel_rays(c2w, intr, size, size)
        t = -o[..., 2] / d[..., 2]
        hit = o + t[..., None] * d
        inside = (hit[..., 0].abs() <= half) & (hit[..., 1].abs() <= half) & (t > 0)
        c2ws.append(c2w[0])
        means.append(torch.where(inside[..., None], hit, o + d).reshape(-1, 3))
        keeps.append(inside.reshape(-1))
    c2w = torch.stack(c2ws)
    return torch.cat(means), torch.cat(keeps), c2w, intr.expand(len(c2ws), 4)


def test_oblique_view_dominated_where_frontal_covers():
    size = 32
    means, keep, c2w, intr = _rig([89.0, 30.0], [0.0, 0.0], size)
    normals = grid_normals(means, keep, c2w).reshape(-1, 3)
    dom = dominated(means, normals, keep, c2w, intr)
    n = size * size
    frontal, oblique = dom[:n], dom[n:]
    assert not frontal.any()  # the most frontal view keeps all of its layer
    assert not dom[~keep].any()
    # the oblique view's Gaussians the frontal view sees (inside its frame, on the plane) are dominated
    uv, z = camera.project(means[n:], c2w[:1], intr[:1])
    seen = keep[n:] & (uv[0] >= 1).all(-1) & (uv[0] < size - 1).all(-1) & (z[0] > 0)
    assert seen.sum() > 100
    assert oblique[seen].float().mean() > 0.9


def test_no_point_loses_every_layer():
    """Two views that see the plane equally obliquely from opposite sides: each one's near half is the more frontal
    (perspective), so each drops its far half, and every dropped Gaussian lands on a kept one of the other view: no
    hole opens."""
    size = 32
    means, keep, c2w, intr = _rig([45.0, 45.0], [0.0, 180.0], size)
    normals = grid_normals(means, keep, c2w).reshape(-1, 3)
    dom = dominated(means, normals, keep, c2w, intr)
    n = size * size
    assert 0 < dom[:n].sum() < keep[:n].sum() and 0 < dom[n:].sum() < keep[n:].sum()
    for own, other in ((slice(0, n), 1), (slice(n, 2 * n), 0)):
        uv, _ = camera.project(means[own][dom[own]], c2w[other : other + 1], intr[other : other + 1])
        px = uv[0].floor().long()
        idx = other * n + px[:, 1] * size + px[:, 0]
        assert keep[idx].all() and not dom[idx].any()


def test_other_surface_is_not_the_same_point():
    """A frontal view whose layer floats well above the oblique view's surface covers nothing of it."""
    means, keep, c2w, intr = _rig([89.0, 30.0], [0.0, 0.0])
    means[: means.shape[0] // 2, 2] += 0.3
    normals = grid_normals(means, keep, c2w).reshape(-1, 3)
    assert not dominated(means, normals, keep, c2w, intr).any()


def _ring(V: int, H: int):
    """V cameras 2.6 away around the origin, 45 degrees apart, alternately level and 30 degrees up, 50-degree field
    of H x H pixels: c2w (V, 4, 4), intr (V, 4) and their pixel rays o, d (V, H, H, 3)."""
    intr = torch.tensor(camera.intrinsics_from_fov(50, H, H), dtype=torch.float32).expand(V, 4).clone()
    c2w = torch.stack(
        [torch.tensor(camera.look_at(camera.spherical_to_cartesian(45.0 * i, 30.0 * (i % 2), 2.6))) for i in range(V)]
    ).float()
    return (c2w, intr, *camera.pixel_rays(c2w, intr, H, H))


def test_backbone_and_cache_agree_on_what_is_rendered():
    """A tiny untrained backbone on a sphere seen by 8 views: with ``view_select`` its reconstruction renders fewer
    Gaussians than the foreground pixels; the cache entry keeps every foreground pixel (F-RNG reads their features)
    and gives exactly the dropped ones opacity 0, and its far-side copies are those made without the selection."""
    from frng.priors import backbone as bb
    from frng.priors.cache import geometry_entry

    V, H = 8, 16
    c2w, intr, o, d = _ring(V, H)
    b = (o * d).sum(-1)
    alpha = ((b * b - (o * o).sum(-1) + 0.25) > 0).float()[..., None]
    imgs = torch.full((V, H, H, 3), 0.5) * alpha
    tiny = {"width": 32, "heads": 2, "geo_depth": 1, "app_depth": 1, "env_height": 8, "sh_degree": 1, "patch": 8}
    entries = {}
    for on in (False, True):
        torch.manual_seed(0)
        m = bb.build(dict(tiny, den_views=2, view_select=on)).eval()
        recon = m.reconstruct(imgs, alpha, c2w, intr, torch.ones(8, 16, 3))  # input light (light_cue_input: known)
        entries[on] = (recon.keep, geometry_entry(m, recon, alpha, c2w, intr))
    fg = alpha.reshape(-1) >= 0.5
    keep_off, off = entries[False]
    keep_on, on = entries[True]
    assert torch.equal(keep_off, fg) and (keep_on <= fg).all() and 0 < int((fg & ~keep_on).sum()) < int(fg.sum())
    assert torch.equal(on["keep"].bool(), fg) and torch.equal(off["keep"].bool(), fg)
    dropped = fg & ~keep_on
    assert (on["opacities"][dropped] == 0).all()
    assert torch.equal(on["opacities"][~dropped], off["opacities"][~dropped])
    for k in ("means", "opacities", "src"):
        assert torch.equal(on["back_" + k], off["back_" + k]), k


def test_training_renders_the_inference_geometry_with_gradients():
    """``RelitLRMBackbone.inference_geometry`` (what ``reconstruct`` renders, and with
    ``backbone.train.inference_geometry`` what the loss renders): on the plane seen frontally and obliquely the
    oblique view's dominated layer leaves ``keep``, the shapes become surfels (not the learned near-points), and a
    loss on the result reaches the means and opacities (the surfels' planes carry no gradient)."""
    from frng.gaussians import Gaussians
    from frng.priors import backbone as bb
    from frng.priors.surfels import pixel_surfels

    size = 32
    means, keep, c2w, intr = _rig([89.0, 30.0], [0.0, 0.0], size)
    N = means.shape[0]
    means = means.clone().requires_grad_(True)
    opac = torch.full((N,), 0.5, requires_grad=True)
    quats = torch.tensor([1.0, 0.0, 0.0, 0.0]).expand(N, 4)
    g = Gaussians(means, quats, torch.full((N, 3), 0.002), opac, torch.zeros(N, 3))
    tiny = {"width": 32, "heads": 2, "geo_depth": 1, "app_depth": 1, "env_height": 8, "sh_degree": 1, "patch": 8}
    m = bb.build(dict(tiny, den_views=2))
    assert m.cfg.surfels and m.cfg.view_select
    out, kept = m.inference_geometry(g, keep, c2w, intr)
    assert (kept <= keep).all() and int((keep & ~kept)[size * size :].sum()) > 0  # the oblique view loses a layer
    assert torch.equal(kept[: size * size], keep[: size * size])  # the frontal view keeps its own
    ref = pixel_surfels(g, keep, c2w, intr)
    assert torch.allclose(out.scales, ref.scales) and not torch.allclose(out.scales, g.scales)
    (out.means[kept].sum() + out.scales[kept].sum() + out.opacities[kept].sum()).backward()
    assert means.grad is not None and means.grad[kept].abs().sum() > 0
    assert opac.grad is not None and torch.equal(opac.grad[kept], torch.ones(int(kept.sum())))
    off = bb.build(dict(tiny, den_views=2, surfels=False, view_select=False, silhouette_cull=False))
    same, same_keep = off.inference_geometry(g, keep, c2w, intr)
    assert same is g and same_keep is keep


def test_silhouette_cull_drops_floaters_only():
    """``backbone.silhouette_cull``: per-pixel Gaussians of a sphere seen by 8 views, on its surface, are all rendered;
    the ones whose depth is pushed off the surface along their own ray (a silhouette pixel that took the
    background's distance) land on another view's background and are not; without the key they are."""
    from frng.gaussians import Gaussians
    from frng.priors import backbone as bb
    from frng.priors.backbone_config import BackboneConfig

    V, H, R = 8, 24, 0.5
    c2w, intr, o, d = _ring(V, H)
    b = (o * d).sum(-1)
    disc = b * b - (o * o).sum(-1) + R * R
    fg = disc > 0
    t = torch.where(fg, -b - disc.clamp_min(0).sqrt(), torch.full_like(b, 2.6))
    t = t.reshape(-1).clone()
    g = torch.Generator().manual_seed(0)
    floaters = fg.reshape(-1) & (torch.rand(t.shape, generator=g) < 0.05)
    t[floaters] += 1.5  # beyond the far side of the sphere (diameter 1): off the object
    means = o.reshape(-1, 3) + d.reshape(-1, 3) * t[:, None]
    N = means.shape[0]
    gauss = Gaussians(means, torch.tensor([1.0, 0, 0, 0]).expand(N, 4), torch.full((N, 3), 0.01), torch.ones(N))
    tiny = {"width": 32, "heads": 2, "geo_depth": 1, "app_depth": 1, "env_height": 8, "sh_degree": 1, "patch": 8}
    keep = fg.reshape(-1)
    rendered = {}
    for on in (False, True):
        m = bb.build(dict(tiny, surfels=False, view_select=False, silhouette_cull=on)).eval()
        rendered[on] = m.inference_geometry(gauss, keep, c2w, intr)[1]
    assert torch.equal(rendered[False], keep)
    assert not (rendered[True] & floaters).any()  # every floater is off some view's silhouette
    assert (rendered[True] == (keep & ~floaters)).float().mean() > 0.999  # and the surface stays
    assert BackboneConfig.from_saved({**tiny, **bb.build(tiny).cfg.to_dict(), "silhouette_cull": True}).silhouette_cull
    saved = {k: v for k, v in bb.build(tiny).cfg.to_dict().items() if k != "silhouette_cull"}
    assert not BackboneConfig.from_saved(saved).silhouette_cull  # models saved before the key: off
