"""Hull fill (frng.priors.hullfill) on an analytic cube: what no input view saw gets a surface, what one saw does
not."""

import numpy as np
import pytest
import torch

from frng import camera
from frng.priors.hullfill import TOL_VOXELS, hull_fill_gaussians
from frng.priors.multiview import back_gaussians, mirror_normals
from frng.priors.surfels import grid_normals
from frng.render.project import quat_to_rotmat

HALF = 0.45  # the cube's half size
DIST = 2.6
RES = 40
H_VOX = 2.0 * 1.05 / 48  # the default grid's spacing


def _views(angles):
    c2w = np.stack([camera.look_at(camera.spherical_to_cartesian(az, el, DIST)) for az, el in angles])
    intr = np.stack([camera.intrinsics_from_fov(50.0, RES, RES)] * len(angles))
    return torch.tensor(c2w, dtype=torch.float32), torch.tensor(intr, dtype=torch.float32)


def _cube(angles):
    """Per-pixel Gaussians of an axis-aligned cube at its true depths, as the backbone would place them."""
    c2w, intr = _views(angles)
    o, d = camera.pixel_rays(c2w, intr, RES, RES)
    inv = 1.0 / torch.where(d.abs() < 1e-9, torch.full_like(d, 1e-9), d)
    t0 = torch.minimum((-HALF - o) * inv, (HALF - o) * inv).amax(-1)
    t1 = torch.maximum((-HALF - o) * inv, (HALF - o) * inv).amin(-1)
    hit = t1 > t0
    alpha = hit.float()[..., None]
    t = torch.where(hit, t0, torch.full_like(t0, DIST))
    means = (o + d * t[..., None]).reshape(-1, 3)
    N = means.shape[0]
    fx = intr[:, 0].repeat_interleave(RES * RES)
    scales = (0.5 * t.reshape(-1) / fx)[:, None].expand(N, 3).contiguous()
    quats = torch.tensor([1.0, 0.0, 0.0, 0.0]).expand(N, 4)
    return means, quats, scales, torch.full((N,), 0.9), alpha, c2w, intr


def _fills(angles, with_copies=True):
    means, quats, scales, opac, alpha, c2w, intr = _cube(angles)
    keep = alpha.reshape(-1) >= 0.5
    back = back_gaussians(means, quats, scales, opac, alpha, c2w, intr, far=4.0) if with_copies else None
    fill = hull_fill_gaussians(means, scales, opac, keep, alpha, c2w, intr, extra=back)
    return fill, means, keep, alpha, c2w, intr


TWO_LEVEL = [(0, 0), (90, 0)]
RIG = [(0, 0), (90, 0), (180, 0), (270, 0), (45, 45), (225, 45)]


def test_two_level_views_get_a_top_and_a_bottom():
    """Two level views see two side faces; the far-side copies stand in for the other two; the fills close the top
    and the bottom, which no view saw, and face out of them."""
    fill, means, keep, *_ = _fills(TWO_LEVEL)
    p = fill["means"]
    assert len(p) > 100
    # on the object's surface or outside it (the hull of two views is loose), never inside
    assert float(p.abs().max(-1).values.min()) >= HALF - H_VOX
    on_cap = (p[:, 2].abs() - HALF).abs() <= 2.0 * H_VOX
    assert int((on_cap & (p[:, 2] > 0)).sum()) > 50 and int((on_cap & (p[:, 2] < 0)).sum()) > 50
    # the top face is covered: every point of it has a fill nearby (but for the part behind the far-side copies,
    # which stand inside the cube where the centroid of the seen faces puts their mirror plane)
    g = torch.linspace(-0.2, HALF - 0.05, 9)
    top = torch.stack(torch.meshgrid(g, g, indexing="ij"), -1).reshape(-1, 2)
    top = torch.cat([top, torch.full((len(top), 1), HALF)], -1)
    assert float(torch.cdist(top, p).min(-1).values.max()) < 3.0 * H_VOX
    # flat, facing out of the face it lies on
    n = quat_to_rotmat(fill["quats"])[..., :, 2]
    mid = on_cap & (p[:, :2].abs() < HALF - 3.0 * H_VOX).all(-1)
    assert float((n[mid, 2] * torch.sign(p[mid, 2])).min()) > 0.9
    assert (fill["scales"][:, 2] < 0.5 * fill["scales"][:, 0]).all()
    # colour and opacity come from a foreground pixel; its normal mirrors onto the fill's
    assert keep[fill["src"]].all()
    src_n = grid_normals(means, keep, _views(TWO_LEVEL)[0]).reshape(-1, 3)[fill["src"]]
    ok = src_n.norm(dim=-1) > 0.5
    assert torch.allclose(mirror_normals(src_n[ok], fill["dirs"][ok]), n[ok], atol=1e-3)


def test_fills_never_cover_what_a_view_saw():
    """Every fill lies behind (or on) the surface each input view reconstructed at its pixel."""
    fill, means, keep, alpha, c2w, intr = _fills(TWO_LEVEL)
    V = c2w.shape[0]
    for v in range(V):
        rel = fill["means"] - c2w[v, :3, 3]
        pc = rel @ c2w[v, :3, :3]
        u = (intr[v, 0] * pc[:, 0] / pc[:, 2] + intr[v, 2]).long().clamp(0, RES - 1)
        w = (intr[v, 1] * pc[:, 1] / pc[:, 2] + intr[v, 3]).long().clamp(0, RES - 1)
        px = v * RES * RES + w * RES + u
        seen = keep[px]
        depth = (means[px] - c2w[v, :3, 3]).norm(dim=-1)
        assert (rel.norm(dim=-1)[seen] >= depth[seen] - TOL_VOXELS * H_VOX - 1e-4).all()


def test_gaussians_already_there_count_as_surface():
    """Gaussians on the two unseen side faces (as far-side copies would be) keep the fills off those faces: a fill
    outside them would swell the object."""
    means, quats, scales, opac, alpha, c2w, intr = _cube(TWO_LEVEL)
    keep = alpha.reshape(-1) >= 0.5
    g = torch.linspace(-HALF, HALF, 31)
    a, b = (t.reshape(-1) for t in torch.meshgrid(g, g, indexing="ij"))
    faces = torch.cat(
        [torch.stack([torch.full_like(a, -HALF), a, b], -1), torch.stack([a, torch.full_like(a, -HALF), b], -1)]
    )
    extra = {"means": faces, "scales": torch.full_like(faces, 0.02), "opacities": torch.full((len(faces),), 0.9)}
    bare = hull_fill_gaussians(means, scales, opac, keep, alpha, c2w, intr)["means"]
    fill = hull_fill_gaussians(means, scales, opac, keep, alpha, c2w, intr, extra=extra)["means"]

    def on_far_faces(p):
        inner = HALF - 3.0 * H_VOX  # the faces' interiors (the hull's loose corners lie beyond their edges)
        x_face = ((p[:, 0] + HALF).abs() < H_VOX) & (p[:, 1].abs() < inner)
        y_face = ((p[:, 1] + HALF).abs() < H_VOX) & (p[:, 0].abs() < inner)
        return (x_face | y_face) & (p[:, 2].abs() < inner)

    assert int(on_far_faces(bare).sum()) > 50
    assert int(on_far_faces(fill).sum()) == 0
    # the top and the bottom are still filled
    assert int(((fill[:, 2].abs() - HALF).abs() <= 2.0 * H_VOX).sum()) > 100


@pytest.mark.parametrize("angles", [RIG], ids=["rig"])
def test_the_rig_sees_the_top_and_leaves_the_bottom(angles):
    """The 6-view rig's 45-degree views see the top: the fills go to the bottom, which no view of the rig sees."""
    fill, *_ = _fills(angles)
    p = fill["means"]
    assert len(p) > 50
    assert float((p[:, 2] < -HALF + 2.0 * H_VOX).float().mean()) > 0.9
    assert int((p[:, 2] > 0).sum()) < 0.05 * len(p)


def test_no_foreground_no_fill():
    means, quats, scales, opac, alpha, c2w, intr = _cube(TWO_LEVEL)
    keep = torch.zeros(means.shape[0], dtype=torch.bool)
    fill = hull_fill_gaussians(means, scales, opac, keep, alpha * 0, c2w, intr)
    assert all(len(t) == 0 for t in fill.values())
    assert fill["means"].shape == (0, 3) and fill["quats"].shape == (0, 4) and fill["src"].dtype == torch.long


def test_the_backbone_appends_the_fills_to_the_copies_and_old_models_keep_none(tmp_path):
    """``backbone.hull_fill`` (default on) appends the fills to the far-side copies of a cache entry; a model.pt saved
    before the key loads with it off (its caches were built without fills)."""
    from dataclasses import replace

    from test_priors_units import TINY

    from frng.gaussians import Gaussians
    from frng.priors import backbone as bb
    from frng.priors import load_backbone

    m = bb.build(dict(TINY))
    assert m.cfg.hull_fill
    means, quats, scales, opac, alpha, c2w, intr = _cube(TWO_LEVEL)
    gauss = Gaussians(means, quats, scales, opac)
    with_fill = m.back_gaussians(gauss, alpha, c2w, intr)
    m.cfg = replace(m.cfg, hull_fill=False)
    copies = m.back_gaussians(gauss, alpha, c2w, intr)
    n = len(copies["src"])
    assert len(with_fill["src"]) > n + 100
    for k, v in copies.items():
        assert torch.equal(with_fill[k][:n], v), k
    old = {k: v for k, v in bb.build(dict(TINY)).cfg.to_dict().items() if k != "hull_fill"}
    torch.save({"kind": "relitlrm", "config": old, "state_dict": m.state_dict()}, tmp_path / "old.pt")
    assert not load_backbone(tmp_path / "old.pt").cfg.hull_fill
