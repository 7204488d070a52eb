"""The multi-view geometry cues (frng.priors.multiview) on an analytic sphere seen by the paper's 6-view rig."""

import math

import numpy as np
import torch

from frng import camera
from frng.priors.multiview import depth_normals, geometry_cues, hull_distance, inside_silhouettes, ray_sphere

R_SPHERE = 0.6
DIST = 2.6


def _rig(res: int):
    angles = [(0, 0), (90, 0), (180, 0), (270, 0), (45, 45), (225, 45)]
    c2w = np.stack([camera.look_at(camera.spherical_to_cartesian(az, el, DIST)) for az, el in angles])
    intr = np.stack([camera.intrinsics_from_fov(50.0, res, res)] * len(angles))
    return torch.tensor(c2w, dtype=torch.float32), torch.tensor(intr, dtype=torch.float32)


def _sphere_views(res: int = 48):
    """Masks, colours and true ray distances of a sphere of radius R_SPHERE at the origin."""
    c2w, intr = _rig(res)
    o, d = camera.pixel_rays(c2w, intr, res, res)
    t0, _, hit = ray_sphere(o, d, R_SPHERE)
    alpha = hit.float()[..., None]
    pts = o + d * t0[..., None]
    rgb = (0.5 + 0.4 * pts / R_SPHERE).clamp(0, 1) * alpha  # a colour that varies over the surface
    return rgb, alpha, c2w, intr, t0, hit


def test_ray_sphere_distances():
    o = torch.tensor([[0.0, 0.0, -3.0]])
    d = torch.tensor([[0.0, 0.0, 1.0]])
    t0, t1, hit = ray_sphere(o, d, 1.0)
    assert hit.item() and math.isclose(t0.item(), 2.0, abs_tol=1e-6) and math.isclose(t1.item(), 4.0, abs_tol=1e-6)
    _, _, miss = ray_sphere(o + torch.tensor([[2.0, 0.0, 0.0]]), d, 1.0)
    assert not miss.item()


def test_hull_distance_interpolates_the_crossing():
    t = torch.linspace(0, 1, 11)
    occ = torch.clamp((t - 0.4) / 0.2, 0, 1)  # crosses 0.5 at t = 0.5
    dist, hit = hull_distance(occ, t, far=9.0)
    assert hit.item() and math.isclose(dist.item(), 0.5, abs_tol=1e-6)
    dist, hit = hull_distance(torch.zeros(11), t, far=9.0)
    assert not hit.item() and dist.item() == 9.0


def test_hull_of_a_sphere_is_the_sphere():
    rgb, alpha, c2w, intr, t_true, hit = _sphere_views()
    cues = geometry_cues(rgb, alpha, c2w, intr, near=1.0, far=4.5)
    inner = hit & (alpha[..., 0] > 0.5)
    # erode by one pixel: silhouette pixels are where a 6-view hull is loosest
    inner = inner & inner.roll(1, 1) & inner.roll(-1, 1) & inner.roll(1, 2) & inner.roll(-1, 2)
    err = (cues["distance"][..., 0] - t_true)[inner].abs()
    # 6 views of a sphere: the hull bulges out between the views (most where the ray grazes the surface)
    assert err.mean() < 0.03, err.mean()
    assert err.max() < 0.25, err.max()  # grazing rays near a view's silhouette
    assert torch.equal(cues["hit"][..., 0].bool() & inner, inner)
    # outside the mask the ray never enters the hull: far
    assert (cues["distance"][..., 0][~hit] == 4.5).all()
    # photo agreement: higher for a colour painted on the surface than for per-pixel noise (inconsistent views)
    noise = torch.rand(rgb.shape, generator=torch.Generator().manual_seed(0)) * alpha
    noisy = geometry_cues(noise, alpha, c2w, intr, near=1.0, far=4.5)
    assert cues["agreement"][inner].mean() > 2 * noisy["agreement"][inner].mean()
    assert cues["features"].shape == (6, 48, 48, 6)


def test_depth_normals_of_a_plane_face_the_camera():
    c2w, intr = _rig(16)
    o, d = camera.pixel_rays(c2w[:1], intr[:1], 16, 16)
    # plane x = 0.3 seen by the camera on +X looking at the origin: world normal +X = camera -z
    t = (0.3 - o[..., 0]) / d[..., 0]
    n = depth_normals(o + d * t[..., None], c2w[:1], torch.ones(1, 16, 16, dtype=torch.bool))
    assert torch.allclose(n, torch.tensor([0.0, 0.0, -1.0]).expand_as(n), atol=1e-4)


def test_back_completion_fills_what_few_views_miss():
    """2 views 90 degrees apart miss half the sphere: their pixels get far-side copies on the sphere's far side,
    facing away from their view; with the 6-view rig almost nothing is unseen."""
    from frng.priors.multiview import back_gaussians, back_surface, mirror_normals

    rgb, alpha, c2w, intr, t0, hit = _sphere_views(32)
    _, unseen6 = back_surface(alpha, c2w, intr, far=4.0)
    fg6 = alpha[..., 0] >= 0.5
    assert float(unseen6.sum()) / float(fg6.sum()) < 0.08
    two = [0, 1]
    a2, c2, i2 = alpha[two], c2w[two], intr[two]
    _, unseen2 = back_surface(a2, c2, i2, far=4.0)
    assert float(unseen2.sum()) / float((a2[..., 0] >= 0.5).sum()) > 0.35
    o, d = camera.pixel_rays(c2, i2, 32, 32)
    means = (o + d * t0[two][..., None]).reshape(-1, 3)
    N = means.shape[0]
    back = back_gaussians(
        means,
        torch.tensor([1.0, 0, 0, 0]).expand(N, 4),
        torch.full((N, 3), 0.01),
        torch.full((N,), 0.9),
        a2,
        c2,
        i2,
        far=4.0,
    )
    M = back["means"].shape[0]
    assert M == int(unseen2.sum()) and back["src"].max() < N
    # on the sphere's far side, behind the source point along its ray
    r = back["means"].norm(dim=-1)
    assert (r <= 1.05 + 1e-4).all() and R_SPHERE - 0.1 < float(r.mean()) < R_SPHERE + 0.1
    ahead = ((back["means"] - means[back["src"]]) * back["dirs"]).sum(-1)
    assert (ahead > 0.05).all() and float(ahead.mean()) > 0.5
    # the mirror image through the centre is nearer the sphere than the 2-view hull's exit (loose: its corners
    # reach out towards the bounding sphere), which it never passes
    exit_, _ = back_surface(a2, c2, i2, far=4.0)
    hull = (o + d * exit_[..., None]).reshape(-1, 3)[back["src"]]
    err_copy = float((r - R_SPHERE).abs().mean())
    err_hull = float((hull.norm(dim=-1) - R_SPHERE).abs().mean())
    assert err_copy < 0.8 * err_hull, (err_copy, err_hull)
    assert (ahead <= ((hull - means[back["src"]]) * back["dirs"]).sum(-1) + 1e-4).all()
    # the copied normal (the source's outward normal, facing its camera) is mirrored to face away from it
    n_src = means[back["src"]] / R_SPHERE
    n_back = mirror_normals(n_src, back["dirs"])
    assert ((n_back * back["dirs"]).sum(-1) > 0).all() and torch.allclose(n_back.norm(dim=-1), torch.ones(M))


def test_inside_silhouettes_is_the_visual_hull():
    _, alpha, c2w, intr, _, _ = _sphere_views()
    g = torch.Generator().manual_seed(0)
    dirs = torch.nn.functional.normalize(torch.randn(500, 3, generator=g), dim=-1)
    on_surface = dirs * R_SPHERE * 0.98
    assert inside_silhouettes(on_surface, alpha, c2w, intr).all()  # every point of the object is in every mask
    assert inside_silhouettes(torch.zeros(1, 3), alpha[..., 0], c2w, intr).all()  # (V, H, W) masks too
    off = dirs * R_SPHERE * 1.5  # a haze around the object: outside some view's silhouette
    assert not inside_silhouettes(off, alpha, c2w, intr).any()
    # a point just outside the mask passes with the 1-pixel tolerance only
    footprint = DIST / intr[0, 0].item()  # one pixel at the sphere's distance, world units
    edge = torch.tensor([[0.0, 0.0, R_SPHERE + 0.7 * footprint]])  # beside the level views' silhouettes
    assert inside_silhouettes(edge, alpha, c2w, intr, dilate_px=2).all()
    assert not inside_silhouettes(edge, alpha, c2w, intr, dilate_px=0).all()


def test_native_hull_sweep_is_the_reference_bit_for_bit():
    """The C++ occupancy kernel (frng/render/csrc/hull.cpp) returns the same floats as the PyTorch reference: soft
    mask edges (bilinear weights matter), samples behind some cameras (a camera inside the bounding sphere), any
    thread count; and the cues built on it are the same bytes."""
    import pytest

    from frng.priors.multiview import occupancy, rays_occupancy
    from frng.render import native

    if not native.available():
        pytest.skip(f"the C++ kernels do not build here: {native.reason()}")
    rgb, alpha, c2w, intr, _, _ = _sphere_views(40)
    soft = torch.nn.functional.avg_pool2d(alpha.permute(0, 3, 1, 2), 3, stride=1, padding=1).permute(0, 2, 3, 1)
    c2w = c2w.clone()
    c2w[5, :3, 3] *= 0.35  # this camera sits inside the sweep's sphere: part of every other view's rays is behind it
    ref, t, o, d = occupancy(soft, c2w, intr, bins=32, kernel="torch")
    assert (ref > 0).any() and ((ref > 0) & (ref < 1)).any()
    threads = torch.get_num_threads()
    try:
        for n in (1, 2):
            torch.set_num_threads(n)
            assert torch.equal(occupancy(soft, c2w, intr, bins=32, kernel="native")[0], ref)
    finally:
        torch.set_num_threads(threads)
    # rays that leave the image of some view and rays of empty pixels: still the reference's values
    R = o.reshape(-1, 3)[::7]
    args = (soft, R, d.reshape(-1, 3)[::7], t.reshape(-1, 32)[::7], c2w, intr)
    assert torch.equal(rays_occupancy(*args, kernel="native"), rays_occupancy(*args, kernel="torch"))
    a = geometry_cues(rgb, soft, c2w, intr, near=1.0, far=4.5, kernel="native")
    b = geometry_cues(rgb, soft, c2w, intr, near=1.0, far=4.5, kernel="torch")
    assert all(torch.equal(a[k], b[k]) for k in a)


def test_inside_silhouettes_unseen_views_say_nothing():
    """With ``unseen_inside`` a view that a point projects outside of (or lies behind) does not cull it; a view that
    sees it on its background still does."""
    _, alpha, c2w, intr, _, _ = _sphere_views()
    p = torch.tensor([[0.0, 9.0, 0.0]])  # far out along the axis of views 1 and 3: view 3 sees it behind the sphere
    uv, z = camera.project(p, c2w, intr)
    W = alpha.shape[2]
    seen = ((z > 0) & (uv[..., 0] >= 0) & (uv[..., 0] < W) & (uv[..., 1] >= 0) & (uv[..., 1] < W))[:, 0]
    assert seen.tolist() == [False, False, False, True, False, False]  # view 1 has it behind, the rest out of frame
    assert not inside_silhouettes(p, alpha, c2w, intr).any()  # by default the views that cannot see it cull it
    assert inside_silhouettes(p, alpha, c2w, intr, unseen_inside=True).all()  # view 3 sees it on the sphere
    hole = alpha.clone()
    hole[3, 20:28, 20:28] = 0.0  # view 3 now sees background there
    assert not inside_silhouettes(p, hole, c2w, intr, unseen_inside=True).any()
    off = torch.tensor([[R_SPHERE * 1.5, 0.0, 0.0]])  # beside the sphere in views 1 and 3
    assert not inside_silhouettes(off, alpha, c2w, intr, unseen_inside=True).any()


def test_hull_sweep_stops_at_the_first_crossing():
    """``rays_occupancy(stop=level)`` zeroes each ray's samples after its first at or above the level (the native
    kernel does not compute them), both kernels alike, and the hull distance at that level is unchanged."""
    import pytest

    from frng.priors.multiview import occupancy, rays_occupancy
    from frng.render import native

    _, alpha, c2w, intr, _, _ = _sphere_views(40)
    soft = torch.nn.functional.avg_pool2d(alpha.permute(0, 3, 1, 2), 3, stride=1, padding=1).permute(0, 2, 3, 1)
    full, t, o, d = occupancy(soft, c2w, intr, bins=32, kernel="torch")
    fg = soft[..., 0] > 0.02
    args = (soft, o[fg], d[fg], t[fg], c2w, intr)
    kernels = ["torch"] + (["native"] if native.available() else [])
    for kernel in kernels:
        cut = rays_occupancy(*args, kernel=kernel, stop=0.5)
        ref = full[fg]
        first = (ref >= 0.5).int().cumsum(-1)
        keep = (first == 0) | ((first == 1) & (ref >= 0.5))
        assert torch.equal(cut[keep], ref[keep]) and not cut[~keep].any()
        assert (~keep).any()  # samples after the crossing exist on a sphere: the test cuts something
        for a, b in zip(hull_distance(cut, t[fg], 4.5), hull_distance(ref, t[fg], 4.5)):
            assert torch.equal(a, b)
    if not native.available():
        pytest.skip(f"the C++ kernels do not build here: {native.reason()}")


def test_photo_agreement_on_a_mask_is_the_same_values():
    """``photo_agreement(mask=)`` computes only the masked pixels: there the same floats as the unmasked call (so
    the cues are the same bytes), zero elsewhere."""
    from frng.priors.multiview import photo_agreement

    rgb, alpha, c2w, intr, t0, hit = _sphere_views(40)
    o, d = camera.pixel_rays(c2w, intr, 40, 40)
    dist = torch.where(hit, t0, torch.full_like(t0, 4.5))
    pts = o + d * dist[..., None]
    full = photo_agreement(rgb, alpha, pts, c2w, intr, dist)
    part = photo_agreement(rgb, alpha, pts, c2w, intr, dist, mask=hit)
    assert (full[hit] > 0).any()
    assert torch.equal(part[hit].view(torch.int32), full[hit].view(torch.int32)) and not part[~hit].any()


def _plate_views(res: int = 32, half: float = 0.012, radius: float = 0.5, ss: int = 4):
    """Anti-aliased masks (ss x ss rays per pixel) and the centre rays' true first-hit distances (nan: a miss) of a flat disc
    (radius ``radius``, thickness 2 ``half``) lying in the z = 0 plane: the rig's level views see it edge-on, as a
    line thinner than a pixel."""
    c2w, intr = _rig(res)
    sub = (torch.arange(ss, dtype=torch.float32) + 0.5) / ss
    ys, xs = torch.meshgrid(
        torch.arange(res, dtype=torch.float32), torch.arange(res, dtype=torch.float32), indexing="ij"
    )
    uv = torch.stack([xs[..., None, None] + sub[None, :, None], ys[..., None, None] + sub[:, None]], -1)
    uv = uv.broadcast_to(res, res, ss, ss, 2).reshape(res, res * ss * ss, 2)
    o, d = camera.rays_at(c2w, intr, uv.expand(len(c2w), *uv.shape))  # (V, res, res*ss*ss, 3)
    t = torch.linspace(1.5, 3.7, 2000)
    inside = lambda p: (p[..., 2].abs() < half) & (p[..., 0] ** 2 + p[..., 1] ** 2 < radius**2)  # noqa: E731
    hits, first = [], []
    for v in range(len(c2w)):
        pts = o[v][..., None, :] + d[v][..., None, :] * t[:, None]  # (res, R, T, 3)
        ins = inside(pts)
        hits.append(ins.any(-1).reshape(res, res, ss * ss).float().mean(-1))
        centre = (ss * ss) // 2 + ss // 2  # a ray near the pixel centre
        on = ins.reshape(res, res, ss * ss, -1)[..., centre, :]
        first.append(torch.where(on.any(-1), t[on.float().argmax(-1)], torch.nan))
    return torch.stack(hits)[..., None], c2w, intr, torch.stack(first)


def test_thin_parts_cross_the_hull():
    """A part thinner than a pixel in some views (a plate seen edge-on: its masks there are lines of alpha < 0.5)
    is still on the hull: its foreground pixels cross at half their ray's peak occupancy instead of missing it,
    which put their Gaussians at the far end of the sweep (a fork lying flat rendered as a few blobs)."""
    alpha, c2w, intr, t_true = _plate_views()
    fg = alpha[..., 0] >= 0.5
    assert alpha[:4].max() < 0.5 and fg[4:].sum() > 100  # level views: an edge-on line; 45 degrees: the disc
    cues = geometry_cues(alpha.expand(*alpha.shape[:3], 3), alpha, c2w, intr, near=1.0, far=4.5)
    dist, hit = cues["distance"][..., 0], cues["hit"][..., 0] > 0
    assert hit[fg].all()
    err = (dist - t_true)[fg & t_true.isfinite()].abs()
    assert err.mean() < 0.1 and err.max() < 0.3, (err.mean(), err.max())  # the 4 level views' lines: a pixel thick
    # without the foreground rays' rescue the level views' 1-px lines keep every ray below 0.5
    from frng.priors.multiview import occupancy

    occ, t, _, _ = occupancy(alpha, c2w, intr)
    _, plain_hit = hull_distance(occ, t, far=4.5)
    assert plain_hit[fg].float().mean() < 0.5
    _, rescued = hull_distance(occ, t, far=4.5, thin=fg)
    assert rescued[fg].all() and not rescued[~fg & (alpha[..., 0] > 0) & ~plain_hit].any()
