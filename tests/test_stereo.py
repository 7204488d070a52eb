"""Multi-view stereo inside the visual hull (frng.priors.stereo) on analytic objects seen by the paper's 6-view rig:
a textured slab seen obliquely (the hull is a fat prism around it; the colours find the slab) and a sphere (the hull
is the surface; stereo keeps it)."""

import math

import torch

from frng import camera
from frng.priors.multiview import geometry_cues
from frng.priors.stereo import aggregate, stereo_distance
from tests.test_multiview import _rig, _sphere_views

HALF = torch.tensor([0.55, 0.05, 0.6])  # the slab's half extents: wide, thin, tall
YAW = math.radians(30.0)  # turned about z between the level views at azimuths 0 and 90


def _slab_views(res: int = 48):
    """Masks, textured colours and true first-hit distances (inf: a miss) of the slab at the origin."""
    c2w, intr = _rig(res)
    o, d = camera.pixel_rays(c2w, intr, res, res)
    c, s = math.cos(YAW), math.sin(YAW)
    rot = torch.tensor([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])  # local -> world
    ol, dl = o @ rot, d @ rot  # world -> local (rot is orthonormal)
    inv = 1.0 / torch.where(dl.abs() < 1e-9, torch.full_like(dl, 1e-9), dl)
    t1, t2 = (-HALF - ol) * inv, (HALF - ol) * inv
    tn, tf = torch.minimum(t1, t2).amax(-1), torch.maximum(t1, t2).amin(-1)
    hit = (tn < tf) & (tf > 0)
    t = torch.where(hit, tn, torch.full_like(tn, math.inf))
    p = ol + dl * torch.where(hit, tn, torch.zeros_like(tn))[..., None]  # local hit point
    tex = 0.5 + 0.35 * torch.sin(9.0 * p[..., 0]) * torch.sin(7.0 * p[..., 2]) + 0.1 * torch.sin(13.0 * p[..., 1])
    rgb = torch.stack([tex, 1.0 - tex, 0.5 + 0.3 * torch.sin(5.0 * (p[..., 0] + p[..., 2]))], -1).clamp(0, 1)
    alpha = hit.float()[..., None]
    return rgb * alpha, alpha, c2w, intr, t


def test_stereo_finds_a_textured_slab_inside_its_hull():
    rgb, alpha, c2w, intr, t_true = _slab_views()
    hull = geometry_cues(rgb, alpha, c2w, intr, near=1.0, far=4.5)["distance"][..., 0]
    fg = alpha[..., 0] >= 0.5
    hull_err = (hull - t_true)[fg].abs()
    assert hull_err.mean() > 0.06 and (hull_err > 0.1).float().mean() > 0.15  # the hull's prism: in front of the faces
    dist = stereo_distance(rgb, alpha, c2w, intr, hull)
    err = (dist - t_true)[fg].abs()
    # the colours move it toward the faces; the hull prior (1 per unit behind the hull) keeps part of the prism
    assert err.mean() < 0.9 * hull_err.mean(), (err.mean(), hull_err.mean())
    assert (err > 0.1).float().mean() < 0.8 * (hull_err > 0.1).float().mean()
    assert torch.equal(dist[~fg], hull[~fg])  # off the object: the hull's value


def test_stereo_keeps_the_hull_on_a_sphere():
    rgb, alpha, c2w, intr, t0, hit = _sphere_views()
    hull = geometry_cues(rgb, alpha, c2w, intr, near=1.0, far=4.5)["distance"][..., 0]
    fg = alpha[..., 0] >= 0.5
    dist = stereo_distance(rgb, alpha, c2w, intr, hull)
    hull_err, err = (hull - t0)[fg].abs(), (dist - t0)[fg].abs()
    assert err.mean() < hull_err.mean() + 0.01, (err.mean(), hull_err.mean())
    uniform = torch.full_like(rgb, 0.6) * alpha  # no texture at all: nothing moves it off the hull
    flat = stereo_distance(uniform, alpha, c2w, intr, hull)
    assert (flat - t0)[fg].abs().mean() < hull_err.mean() + 0.01


def test_aggregation_without_penalties_is_the_cost_and_with_them_outvotes_an_outlier():
    cost = torch.zeros(1, 5, 5, 4)
    cost[..., 1] = -1.0  # label 1 best everywhere ...
    cost[0, 2, 2] = torch.tensor([0.0, 0.0, 0.0, -0.5])  # ... but for one pixel whose own best is label 3
    assert torch.allclose(aggregate(cost, p1=0.0, p2=0.0), 8 * cost)  # 8 paths, no smoothing
    S = aggregate(cost, p1=0.1, p2=0.5)
    assert (S.argmin(-1) == 1).all()  # its neighbours outvote it along all 8 paths
