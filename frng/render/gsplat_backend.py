"""gsplat backend (CUDA only; imported lazily, never required): ``gsplat.rasterization`` with N-D features."""

from __future__ import annotations

import torch


def available() -> bool:
    """True when CUDA is present and gsplat imports."""
    if not torch.cuda.is_available():
        return False
    try:
        import gsplat  # noqa: F401
    except Exception:  # ImportError, or a broken CUDA build
        return False
    return True


def rasterize_gsplat(
    means,
    quats,
    scales,
    opacities,
    features,
    c2w,
    intrinsics,
    height,
    width,
    near=0.01,
    far=1e10,
    eps2d=0.3,
    tile=16,
    **_ignored,
):
    """Shapes as in :func:`frng.render.rasterize`. ``max_radius_px`` is not applied (gsplat has no screen-space
    clamp; on a GPU large footprints cost little). Differences to the PyTorch backend: gsplat bins by a
    3-sigma-ish radius but does not cut at the 3-sigma ellipse inside a tile, so pixels just outside the
    ellipse may receive alpha >= 1/255 when opacity > exp(4.5) / 255 ~ 0.35."""
    from gsplat import rasterization

    V = c2w.shape[0]
    viewmats = torch.linalg.inv(c2w)
    Ks = torch.zeros(V, 3, 3, device=c2w.device, dtype=c2w.dtype)
    Ks[:, 0, 0], Ks[:, 1, 1] = intrinsics[:, 0], intrinsics[:, 1]
    Ks[:, 0, 2], Ks[:, 1, 2], Ks[:, 2, 2] = intrinsics[:, 2], intrinsics[:, 3], 1.0
    colors, alphas, _meta = rasterization(
        means,
        quats,
        scales.clamp(min=0.0),
        opacities.clamp(0.0, 1.0),
        features,
        viewmats,
        Ks,
        width,
        height,
        near_plane=near,
        far_plane=far,
        eps2d=eps2d,
        tile_size=tile,
        render_mode="RGB+D",
        packed=False,
    )
    return colors[..., :-1], alphas, colors[..., -1:]
