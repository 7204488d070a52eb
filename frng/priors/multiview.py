"""Multi-view geometry cues from calibrated input views: a plane sweep along every input pixel's ray.

The learned priors (backbone, IDM) only see a few hundred training objects on the default tier, far too few for a
transformer to learn multi-view stereo from scratch (RelitLRM saw ~1M). What makes geometry sample-efficient is
comparing the views along known camera rays, so this module does that explicitly, without learning:

For every input pixel of view ``v`` the ray ``o + t d`` is cut to the bounding sphere (``radius``; objects live in
the unit sphere) and sampled at ``bins`` distances. Each sample is projected into every input view ``u`` and the
view's alpha (the object mask, known at inference too) is read there (bilinear; outside the image = 0):

    occupancy_k = min_u alpha_u(project_u(o + t_k d))             soft visual hull, (V, H, W, K)

The visual hull's first crossing of 0.5 along the ray (linearly interpolated between samples) is the pixel's
**hull distance** (:func:`hull_distance`); for convex objects it is the surface, for concave ones an upper bound
on how near the surface can be. Pixels whose ray never enters the hull (outside the mask) get the far end; a
foreground pixel whose ray stays below 0.5 (a part thinner than a pixel in some view) crosses at half its peak.

:func:`geometry_cues` bundles what the networks take per pixel: the hull distance normalised to [0, 1] over
``[near, far]``, the normal of the hull's depth map (camera frame, from finite differences of the back-projected
points), and the sweep's per-view colour agreement at the hull point (how well the other views that see the
point in their mask agree on its colour, a photo-consistency confidence).

Shapes: images (V, H, W, C), cameras c2w (V, 4, 4) OpenCV and intrinsics (V, 4); distances along unit rays.
Cost: V^2 H W K bilinear reads (6 views, 64 px, 48 bins: 7M reads, ~0.1 s on 2 CPU cores).
"""

from __future__ import annotations

import torch
import torch.nn.functional as F

from frng import camera
from frng.render.project import quat_to_rotmat, rotmat_to_quat

CUE_CHANNELS = 1 + 3 + 1 + 1  # hull distance (normalised), hull normal (camera frame), photo agreement, hull hit


def ray_sphere(o: torch.Tensor, d: torch.Tensor, radius: float) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Entry/exit distances of unit rays (..., 3) through the sphere |x| = radius at the origin.

    Returns t0, t1 (...) (clamped to >= 0) and hit (...) bool; for misses t0 = t1 = the closest approach."""
    b = (o * d).sum(-1)
    c = (o * o).sum(-1) - radius * radius
    disc = b * b - c
    hit = disc > 0
    s = disc.clamp_min(0).sqrt()
    return (-b - s).clamp_min(0), (-b + s).clamp_min(0), hit


def sample_image(
    images: torch.Tensor, uv: torch.Tensor, padding: str = "zeros", mode: str = "bilinear"
) -> torch.Tensor:
    """Reads of per-view images at pixel coordinates (pixel centres at +0.5), bilinear or ``mode="nearest"``.

    images (V, H, W, C); uv (V, ..., 2) as (x, y) -> (V, ..., C). ``padding``: "zeros" (0 outside the image) or
    "border" (edge pixels replicated), as :func:`torch.nn.functional.grid_sample`."""
    V, H, W, C = images.shape
    lead = uv.shape[1:-1]
    grid = torch.stack([2.0 * uv[..., 0] / W - 1.0, 2.0 * uv[..., 1] / H - 1.0], dim=-1).reshape(V, 1, -1, 2)
    out = F.grid_sample(
        images.permute(0, 3, 1, 2), grid.to(images.dtype), mode=mode, padding_mode=padding, align_corners=False
    )
    return out[:, :, 0].permute(0, 2, 1).reshape(V, *lead, C)


def ray_homogeneous(o: torch.Tensor, d: torch.Tensor, c2w: torch.Tensor, intr: torch.Tensor):
    """Each ray's homogeneous image coordinates in each camera, affine in the distance t: h = A + t B.

    o, d (R, 3); c2w (V, 4, 4); intr (V, 4). Returns A, B (V, R, 3); the pixel is (h0 / h2, h1 / h2), h2 the
    camera-frame z."""
    w2c = torch.linalg.inv(c2w)[:, :3]  # (V, 3, 4)
    Kmat = torch.zeros(c2w.shape[0], 3, 3, device=c2w.device, dtype=c2w.dtype)
    Kmat[:, 0, 0], Kmat[:, 1, 1], Kmat[:, 0, 2], Kmat[:, 1, 2], Kmat[:, 2, 2] = (
        intr[:, 0],
        intr[:, 1],
        intr[:, 2],
        intr[:, 3],
        1.0,
    )
    P = Kmat @ w2c  # (V, 3, 4)
    A = torch.einsum("vij,rj->vri", P[:, :, :3], o) + P[:, None, :, 3]  # (V, R, 3)
    B = torch.einsum("vij,rj->vri", P[:, :, :3], d)
    return A, B


def project_rays(o: torch.Tensor, d: torch.Tensor, t: torch.Tensor, c2w: torch.Tensor, intr: torch.Tensor):
    """Project the points o + t d of R rays at K distances into V cameras, using that a ray's homogeneous image
    coordinates are affine in t (:func:`ray_homogeneous`: two 3x4 products per ray and camera instead of one per
    point).

    o, d (R, 3); t (R, K); c2w (V, 4, 4); intr (V, 4). Returns uv (V, R, K, 2) pixel coordinates and camera-frame
    z (V, R, K)."""
    A, B = ray_homogeneous(o, d, c2w, intr)
    # h = A + t B, (V, R, K, 3), one coordinate at a time (the same arithmetic per element, a third of the memory
    # traffic)
    tt = t[None]
    z = A[:, :, None, 2] + tt * B[:, :, None, 2]
    zs = torch.where(z.abs() < 1e-9, torch.full_like(z, 1e-9), z)
    x = (A[:, :, None, 0] + tt * B[:, :, None, 0]).div_(zs)
    y = (A[:, :, None, 1] + tt * B[:, :, None, 1]).div_(zs)
    return torch.stack([x, y], -1), z


def inside_silhouettes(
    points: torch.Tensor,
    alpha: torch.Tensor,
    c2w: torch.Tensor,
    intr: torch.Tensor,
    dilate_px: int = 1,
    unseen_inside: bool = False,
) -> torch.Tensor:
    """Which points lie inside the visual hull of the input views: in front of every camera and projected onto a
    foreground pixel (alpha > 0.5, the mask dilated by ``dilate_px`` pixels for the masks' own edge error) of every
    view. A point outside one view's silhouette cannot be on the object. ``unseen_inside``: a view the point is
    behind or projects outside of says nothing about it (an object larger than a view's frame keeps its parts
    beyond that frame); by default such a point is outside.

    points (N, 3) world; alpha (V, H, W) or (V, H, W, 1) masks; c2w (V, 4, 4); intr (V, 4). Returns (N,) bool."""
    a = alpha[..., 0] if alpha.dim() == 4 else alpha
    V, H, W = a.shape
    assert points.dim() == 2 and points.shape[-1] == 3, points.shape
    assert c2w.shape == (V, 4, 4) and intr.shape == (V, 4), (c2w.shape, intr.shape, a.shape)
    fg = (a > 0.5).float()[:, None]
    if dilate_px > 0:
        fg = F.max_pool2d(fg, 2 * dilate_px + 1, stride=1, padding=dilate_px)
    fg = fg.permute(0, 2, 3, 1)  # (V, H, W, 1)
    uv, z = camera.project(points.float(), c2w.float(), intr.float())  # (V, N, 2), (V, N)
    seen = (z > 0) & (uv[..., 0] >= 0) & (uv[..., 0] < W) & (uv[..., 1] >= 0) & (uv[..., 1] < H)
    on_fg = (sample_image(fg, uv, mode="nearest")[..., 0] > 0.5) & seen  # (V, N)
    return (on_fg | ~seen if unseen_inside else on_fg).all(dim=0)


def sweep_samples(c2w: torch.Tensor, intr: torch.Tensor, height: int, width: int, bins: int, radius: float):
    """Sample distances (V, H, W, K) inside the bounding sphere and the ray origins/directions (V, H, W, 3)."""
    o, d = camera.pixel_rays(c2w, intr, height, width)
    return sweep_distances(o, d, bins, radius), o, d


def sweep_distances(o: torch.Tensor, d: torch.Tensor, bins: int, radius: float) -> torch.Tensor:
    """``bins`` sample distances (..., K) of rays o, d (..., 3), evenly spaced where they cross the bounding sphere
    (bin centres)."""
    t0, t1, _ = ray_sphere(o, d, radius)
    s = (torch.arange(bins, device=o.device, dtype=o.dtype) + 0.5) / bins
    return t0[..., None] + (t1 - t0)[..., None] * s


def occupancy(
    alpha: torch.Tensor,
    c2w: torch.Tensor,
    intr: torch.Tensor,
    bins: int = 48,
    radius: float = 1.05,
    kernel: str = "auto",
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    """Soft visual hull along every input pixel's ray.

    alpha (V, H, W, 1) masks; c2w (V, 4, 4); intr (V, 4). Returns occupancy (V, H, W, K) in [0, 1], the sample
    distances t (V, H, W, K), ray origins and unit directions (V, H, W, 3). Only rays of pixels with some coverage
    (alpha > 0.02; the pixel's own mask bounds the hull) are swept; the others have occupancy 0. ``kernel``: as
    :func:`rays_occupancy`."""
    V, H, W, _ = alpha.shape
    assert c2w.shape == (V, 4, 4) and intr.shape == (V, 4), (c2w.shape, intr.shape)
    c2w, intr = c2w.float(), intr.float()
    t, o, d = sweep_samples(c2w, intr, H, W, bins, radius)
    fg = alpha[..., 0] > 0.02
    occ = torch.zeros(V, H, W, bins, device=alpha.device)
    if fg.any():
        occ[fg] = rays_occupancy(alpha, o[fg], d[fg], t[fg], c2w, intr, kernel)
    return occ, t, o, d


def rays_occupancy(
    alpha: torch.Tensor,
    o: torch.Tensor,
    d: torch.Tensor,
    t: torch.Tensor,
    c2w: torch.Tensor,
    intr: torch.Tensor,
    kernel: str = "auto",
    stop: float | None = None,
) -> torch.Tensor:
    """Visual-hull occupancy (R, K) of rays o, d (R, 3) at distances t (R, K): the minimum over the V views of
    each view's mask (alpha (V, H, W, 1)) read bilinearly where a sample projects, 0 behind a camera.
    ``stop``: a level; each ray's samples after its first with occupancy >= ``stop`` are 0, and the native kernel
    does not compute them (what :func:`hull_distance` at that level reads is unchanged; inside the hull a sample
    costs a read in every view). None: every sample.

    ``kernel``: "torch" (:func:`occupancy_reference`, every view at every sample), "native" (the C++ kernel
    ``frng/render/csrc/hull.cpp``: a sample stops at the first view that rules it out; the same floats, its bilinear
    reads copy grid_sample's arithmetic), "auto" (native on CPU when the extension loads,
    :func:`frng.render.native.available`). This sweep is the hot loop of the backbone's training step (``frng
    bench cues``)."""
    from frng.render import native

    assert kernel in ("auto", "torch", "native"), kernel
    if kernel == "auto":
        kernel = "native" if alpha.device.type == "cpu" and native.available() else "torch"
    if kernel == "torch":
        occ = occupancy_reference(alpha, o, d, t, c2w, intr)
        if stop is not None:  # zero after the first sample that reaches ``stop``
            reached = (occ >= stop).int().cumsum(-1)
            occ = torch.where((reached == 0) | ((reached == 1) & (occ >= stop)), occ, torch.zeros_like(occ))
        return occ
    A, B = ray_homogeneous(o, d, c2w.float(), intr.float())
    return native.hull_occupancy(alpha[..., 0], A, B, t, stop)


def occupancy_reference(
    alpha: torch.Tensor, o: torch.Tensor, d: torch.Tensor, t: torch.Tensor, c2w: torch.Tensor, intr: torch.Tensor
) -> torch.Tensor:
    """The minimum over the V views of each view's mask, read bilinearly where the samples o + t d project (0
    behind a camera): occupancy (R, K) of rays o, d (R, 3) at distances t (R, K); alpha (V, H, W, 1)."""
    V = alpha.shape[0]
    uv, z = project_rays(o, d, t, c2w, intr)  # (V, R, K, 2), (V, R, K)
    a = sample_image(alpha.float(), uv.reshape(V, -1, 2))[..., 0] * (z.reshape(V, -1) > 0)  # (V_src, R*K)
    return a.min(dim=0).values.reshape(t.shape)


def hull_distance(
    occ: torch.Tensor, t: torch.Tensor, far: float, level: float = 0.5, thin: torch.Tensor | None = None
) -> tuple[torch.Tensor, torch.Tensor]:
    """First crossing of ``level`` along each ray, linearly interpolated between samples.

    occ, t (..., K). ``thin`` (...) bool, optional: rays that lie on the object (foreground pixels); where such a
    ray's occupancy never reaches ``level`` but is above 0 somewhere, the object is thinner there than a pixel in
    some view (a fork lying flat, seen from the side as a 1-px line whose bilinear mask reads stay below 0.5), and
    the ray crosses at ``level`` times its own peak instead (a hit): without this its pixel was put at ``far``.
    Returns distance (...) (``far`` where the ray never enters) and hit (...) bool."""
    if thin is not None:
        assert thin.shape == occ.shape[:-1], (thin.shape, occ.shape)
        peak = occ.max(-1, keepdim=True).values
        rescue = thin[..., None] & (peak < level) & (peak > 0)
        occ = torch.where(rescue, occ / peak.clamp_min(1e-12), occ)
    inside = occ >= level
    hit = inside.any(-1)
    k = inside.float().argmax(-1)  # first inside sample (0 when none)
    kp = (k - 1).clamp_min(0)
    o1 = occ.gather(-1, k[..., None])[..., 0]
    o0 = occ.gather(-1, kp[..., None])[..., 0]
    t1 = t.gather(-1, k[..., None])[..., 0]
    t0 = t.gather(-1, kp[..., None])[..., 0]
    frac = ((level - o0) / (o1 - o0).clamp_min(1e-6)).clamp(0, 1)
    dist = torch.where(k > 0, t0 + frac * (t1 - t0), t1)
    return torch.where(hit, dist, torch.full_like(dist, far)), hit


def back_surface(
    alpha: torch.Tensor,
    c2w: torch.Tensor,
    intr: torch.Tensor,
    far: float,
    bins: int = 48,
    radius: float = 1.05,
    tol: float | None = None,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Where the visual hull's far side lies behind each input pixel, and whether any input view sees it.

    alpha (V, H, W, 1), c2w (V, 4, 4), intr (V, 4). For every foreground pixel the ray's LAST crossing of the hull
    (its exit, :func:`hull_distance` on the reversed sweep) is a point on the hull's far side. It counts as seen
    when, in some input view, it projects inside the image and no farther from that camera than the view's own
    first hull crossing there plus ``tol`` (default two sweep steps): then some view already has a Gaussian on
    that surface. Returns the exit distance (V, H, W) along the pixel's unit ray and ``unseen`` (V, H, W) bool:
    the pixel is foreground (alpha >= 0.5), its ray enters the hull, and no input view sees its exit point. With
    the 6-view rig almost every exit point is seen; with 2 views the whole far half of the object is unseen, which
    is what :func:`back_gaussians` completes."""
    V, H, W, _ = alpha.shape
    tol = 4.0 * radius / bins if tol is None else tol
    occ, t, o, d = occupancy(alpha, c2w, intr, bins, radius)
    on = alpha[..., 0] >= 0.5
    front, hit = hull_distance(occ, t, far, thin=on)
    exit_, _ = hull_distance(occ.flip(-1), t.flip(-1), far, thin=on)
    fg = on & hit & (exit_ > front + tol)
    unseen = fg.clone()
    if fg.any():
        pts = (o + d * exit_[..., None])[fg]  # (R, 3)
        c2w, intr = c2w.float(), intr.float()
        R = c2w[:, :3, :3]
        cam = c2w[:, :3, 3]
        rel = pts[None] - cam[:, None]  # (V, R, 3)
        pc = (R.transpose(-1, -2)[:, None] @ rel[..., None])[..., 0]  # camera frame (V, R, 3)
        z = pc[..., 2]
        u = intr[:, None, 0] * pc[..., 0] / z.clamp_min(1e-6) + intr[:, None, 2]
        v = intr[:, None, 1] * pc[..., 1] / z.clamp_min(1e-6) + intr[:, None, 3]
        uv = torch.stack([u, v], -1)
        front_u = sample_image(front[..., None], uv, mode="nearest")[..., 0]  # (V, R) first crossing there
        inside = (z > 0) & (u >= 0) & (u <= W) & (v >= 0) & (v <= H)
        seen = inside & (rel.norm(dim=-1) <= front_u + tol)
        unseen[fg] = ~seen.any(0)
    return exit_, unseen


def back_gaussians(
    means: torch.Tensor,
    quats: torch.Tensor,
    scales: torch.Tensor,
    opacities: torch.Tensor,
    alpha: torch.Tensor,
    c2w: torch.Tensor,
    intr: torch.Tensor,
    far: float,
    bins: int = 48,
    radius: float = 1.05,
) -> dict[str, torch.Tensor]:
    """Complete the surfaces no input view sees (few views) with copies of the pixels' Gaussians on the far side.

    means/quats/scales/opacities: the N = V*H*W per-pixel Gaussians (N, 3)/(N, 4)/(N, 3)/(N,); alpha (V, H, W, 1);
    c2w (V, 4, 4); intr (V, 4). Each pixel whose hull exit is unseen (:func:`back_surface`) gets one more Gaussian
    on its ray, behind its own: its mirror image across the plane through the object's centre normal to the ray
    (a symmetric object's far side), but no farther than the visual hull's exit. The centre is the centroid of the
    foreground pixels' Gaussians and the unseen exits. The hull alone is loose with few views (two views 90
    degrees apart cut a box around a ball), so copies at the exit stood outside the object and swelled its
    silhouette. A copy is the source Gaussian mirrored across the plane normal to the ray (its covariance reflected,
    its opacity kept), its scale grown with the distance (same footprint in pixels). Returns ``means`` (M, 3),
    ``quats`` (M, 4), ``scales`` (M, 3), ``opacities`` (M,), ``src`` (M,) int64 the source pixel's index in N (whose
    colour or features the copy takes), ``dirs`` (M, 3) the source pixel's unit ray (a copy's normal is the source
    normal mirrored across the plane normal to it: :func:`mirror_normals`)."""
    V, H, W, _ = alpha.shape
    N = V * H * W
    assert means.shape == (N, 3), (means.shape, alpha.shape)
    exit_, unseen = back_surface(alpha, c2w, intr, far, bins, radius)
    o, d = camera.pixel_rays(c2w.float(), intr.float(), H, W)
    src = unseen.reshape(-1).nonzero()[:, 0]
    o, d, t_exit = o.reshape(-1, 3)[src], d.reshape(-1, 3)[src], exit_.reshape(-1)[src]
    front = means[src]
    t_front = (front - o).norm(dim=-1).clamp_min(1e-6)
    if len(src):
        fg = alpha.reshape(-1) >= 0.5
        centre = torch.cat([means[fg], o + d * t_exit[:, None]]).mean(0)
        t_mirror = t_front + 2.0 * ((centre - front) * d).sum(-1).clamp_min(0.0)
        t_exit = torch.minimum(t_exit, t_mirror)
    grow = (t_exit / t_front).clamp(0.5, 4.0)[:, None]
    return {
        "means": o + d * t_exit[:, None],
        "quats": mirror_quats(quats[src], d),
        "scales": scales[src] * grow,
        "opacities": opacities[src],
        "src": src,
        "dirs": d,
    }


def mirror_quats(q: torch.Tensor, d: torch.Tensor) -> torch.Tensor:
    """Rotations (M, 4) (w, x, y, z) of Gaussians mirrored across the planes normal to unit directions d (M, 3):
    the reflection H = I - 2 d d^T applied to the rotation's frame, one axis flipped to keep it a rotation (the
    covariance becomes H R S^2 R^T H, the mirror image's)."""
    Hm = torch.eye(3, device=d.device, dtype=d.dtype) - 2.0 * d[:, :, None] * d[:, None, :]
    R = Hm @ quat_to_rotmat(q).to(d.dtype)
    return rotmat_to_quat(torch.stack([R[..., 0], -R[..., 1], R[..., 2]], -1))


def mirror_normals(n: torch.Tensor, d: torch.Tensor) -> torch.Tensor:
    """Mirror normals (M, 3) across the planes normal to unit directions d (M, 3): ``n - 2 (n . d) d``."""
    return n - 2.0 * (n * d).sum(-1, keepdim=True) * d


def depth_normals(points: torch.Tensor, c2w: torch.Tensor, valid: torch.Tensor) -> torch.Tensor:
    """Camera-frame normals (V, H, W, 3) of world points (V, H, W, 3) on a pixel grid (central differences where
    both neighbours are valid, else one-sided; facing the camera; (0, 0, -1) where nothing is valid)."""
    p = points
    v = valid.float()[..., None]

    def diff(dim: int) -> torch.Tensor:
        fwd = p.roll(-1, dim) - p
        bwd = p - p.roll(1, dim)
        vf = v * v.roll(-1, dim)
        vb = v * v.roll(1, dim)
        n = vf + vb
        return (fwd * vf + bwd * vb) / n.clamp_min(1.0)

    dx, dy = diff(2), diff(1)
    n_world = torch.cross(dx, dy, dim=-1)  # exactly 0 off ``valid`` (no valid neighbour): the default normal there
    sel = valid.bool()
    V, H, W = sel.shape
    Rt = c2w[:, None, None, :3, :3].float().transpose(-1, -2).expand(V, H, W, 3, 3)
    rotated = (Rt[sel] @ n_world[sel].unsqueeze(-1)).squeeze(-1)  # world -> camera where valid (bf16 under autocast)
    n_cam = torch.zeros(V, H, W, 3, device=n_world.device, dtype=rotated.dtype)  # the rest is background
    n_cam[sel] = rotated
    n_cam = torch.where(n_cam[..., 2:3] > 0, -n_cam, n_cam)  # face the camera (camera looks along +z)
    norm = n_cam.norm(dim=-1, keepdim=True)
    default = torch.tensor([0.0, 0.0, -1.0], device=p.device).expand_as(n_cam)
    return torch.where(norm > 1e-9, n_cam / norm.clamp_min(1e-9), default)


def photo_agreement(
    rgb: torch.Tensor,
    alpha: torch.Tensor,
    points: torch.Tensor,
    c2w: torch.Tensor,
    intr: torch.Tensor,
    hull_dist_all: torch.Tensor,
    mask: torch.Tensor | None = None,
) -> torch.Tensor:
    """How well the OTHER views that see each hull point agree with the pixel's own colour (V, H, W, 1) in [0, 1].

    A point is taken as seen by view u when it falls inside u's mask and its distance from u's centre is within a
    small margin of u's hull distance at that pixel (a visibility test against the hull). Agreement =
    exp(-|c_u - c_ref|_1 / 0.1) averaged over those views (gamma-2.2 unpremultiplied colours); 0 if none sees it.
    ``mask`` (V, H, W) bool: only those pixels are computed (the same values there), the others are 0 -- the work
    is V reads per pixel, so a caller that keeps only the hull's pixels passes them."""
    V, H, W, _ = rgb.shape
    col = (rgb / alpha.clamp_min(1e-3)).clamp(0, 1) ** (1 / 2.2)
    sel = torch.ones(V, H, W, dtype=torch.bool, device=rgb.device) if mask is None else mask.bool()
    assert sel.shape == (V, H, W), (sel.shape, rgb.shape)
    pts = points[sel]  # (N, 3), N <= V*H*W
    own = torch.arange(V, device=rgb.device)[:, None, None].expand(V, H, W)[sel]  # each point's own view
    ref = col[sel]
    n = pts.shape[0]
    pad = -n % 64  # whole SIMD blocks: the selected pixels get the unmasked call's bits (its N = V*H*W is a multiple)
    pts, own, ref = F.pad(pts, (0, 0, 0, pad)), F.pad(own, (0, pad)), F.pad(ref, (0, 0, 0, pad))
    uv, z = camera.project(pts, c2w.float(), intr.float())
    src = sample_image(torch.cat([col, alpha, hull_dist_all[..., None]], -1), uv)  # (V_src, N, 5)
    dist_u = (pts[None] - c2w[:, None, :3, 3].float()).norm(dim=-1)
    seen = (src[..., 3] > 0.5) & (z > 0) & (dist_u <= src[..., 4] + 0.08)
    agree = torch.exp(-(src[..., :3] - ref[None]).abs().sum(-1) / 0.1)
    not_self = torch.ones_like(seen)
    not_self[own, torch.arange(own.shape[0], device=rgb.device)] = False
    w = (seen & not_self).float()
    out = torch.zeros(V, H, W, 1, device=rgb.device, dtype=agree.dtype)
    out[sel] = ((agree * w).sum(0) / w.sum(0).clamp_min(1.0))[:n, None]
    return out


@torch.no_grad()
def geometry_cues(
    rgb: torch.Tensor,
    alpha: torch.Tensor,
    c2w: torch.Tensor,
    intr: torch.Tensor,
    near: float,
    far: float,
    bins: int = 48,
    radius: float = 1.05,
    kernel: str = "auto",
) -> dict[str, torch.Tensor]:
    """Per-pixel geometry cues of one object's input views (no gradients; the inputs are data).

    rgb (V, H, W, 3) linear premultiplied; alpha (V, H, W, 1); c2w (V, 4, 4); intr (V, 4).
    Returns ``distance`` (V, H, W, 1) hull distance along the unit ray (world units; ``far`` off the hull),
    ``normal`` (V, H, W, 3) camera-frame normal of the hull depth map, ``agreement`` (V, H, W, 1),
    ``hit`` (V, H, W, 1) 1 where the ray enters the hull, and ``features`` (V, H, W, CUE_CHANNELS) =
    [(distance - near) / (far - near), normal, agreement, hit] for the networks. ``kernel``: the hull sweep's, as
    :func:`rays_occupancy` (the same bytes either way)."""
    V, H, W, _ = rgb.shape
    assert alpha.shape == (V, H, W, 1), alpha.shape
    c2w, intr = c2w.float(), intr.float()
    o, d = camera.pixel_rays(c2w, intr, H, W)
    fg = alpha[..., 0] > 0.02  # as occupancy(): only these rays are swept, the others miss the hull
    dist = torch.full((V, H, W), far, device=rgb.device)
    hit = torch.zeros(V, H, W, dtype=torch.bool, device=rgb.device)
    if fg.any():
        t = sweep_distances(o[fg], d[fg], bins, radius)  # (R, K)
        occ = rays_occupancy(alpha, o[fg], d[fg], t, c2w, intr, kernel, stop=0.5)  # up to the first crossing
        dist[fg], hit[fg] = hull_distance(occ, t, far, level=0.5, thin=alpha[..., 0][fg] >= 0.5)
    pts = o + d * dist[..., None]
    normal = depth_normals(pts, c2w, hit)
    agree = photo_agreement(rgb.float(), alpha.float(), pts, c2w, intr, dist, mask=hit)
    hitf = hit.float()[..., None]
    feats = torch.cat([((dist[..., None] - near) / (far - near)).clamp(0, 1), normal, agree * hitf, hitf], -1)
    return {"distance": dist[..., None], "normal": normal, "agreement": agree * hitf, "hit": hitf, "features": feats}


__all__ = [
    "CUE_CHANNELS",
    "back_gaussians",
    "back_surface",
    "mirror_normals",
    "depth_normals",
    "geometry_cues",
    "hull_distance",
    "occupancy",
    "photo_agreement",
    "occupancy_reference",
    "project_rays",
    "ray_homogeneous",
    "rays_occupancy",
    "sweep_distances",
    "ray_sphere",
    "sample_image",
    "sweep_samples",
]
