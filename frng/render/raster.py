"""The one functional entry point for rendering 3D Gaussians: :func:`rasterize`, plus its typed config."""

from __future__ import annotations

from dataclasses import dataclass, fields

import torch

from frng.plan.sections import key, register
from frng.render import gsplat_backend
from frng.render.project import project_gaussians
from frng.render.reference import rasterize_reference
from frng.render.tiles import rasterize_tiles

BACKENDS = ("auto", "torch", "native", "gsplat", "reference")


@register("raster")
@dataclass(frozen=True)
class RasterConfig:
    """The config's ``raster`` section (each key declared on its field)."""

    CONFIG_DOC = "Gaussian rasterizer (frng/render/raster.py, RasterConfig)"

    backend: str = key(
        "auto",
        "`auto`: gsplat on CUDA when installed, else `native` on CPU when it builds, else the pure-PyTorch tile "
        "rasterizer `torch`; `native` is that tile rasterizer with its binning and compositing in fused C++ CPU "
        "kernels (built by `make setup`); `reference` is the brute-force test oracle",
        type="string",
        enum=["auto", "torch", "native", "gsplat", "reference"],
    )
    tile_size: int = key(
        4,
        "tile edge (px) of the `torch` and `native` backends; the image does not depend on it, only the speed",
        type="integer",
        minimum=1,
        maximum=64,
    )
    chunk: int = key(
        64,
        "Gaussians per depth chunk (`torch`); early termination is checked between chunks",
        type="integer",
        minimum=1,
        maximum=65536,
    )
    compile: bool = key(
        False,
        "`torch.compile` the compositing kernels of `torch` (first call compiles for a while)",
        type="boolean",
    )
    max_radius_px: float | None = key(
        None,
        "shrink screen footprints whose 3-sigma radius exceeds this (bounds cost); null = no cap",
        type=["number", "null"],
        exclusiveMinimum=0,
        maximum=1024,
    )
    min_transmittance: float = key(
        0.0001,
        "`torch`: a tile stops once all its pixels' transmittance is below this; `native`: each pixel stops once its "
        "own is (0: never)",
        type="number",
        minimum=0,
        maximum=1,
    )
    eps2d: float = key(
        0.3,
        "screen-space low-pass added to the 2D covariance (px^2), as 3DGS/gsplat",
        type="number",
        minimum=0,
    )
    near: float = key(
        0.01,
        "Gaussians closer than this (camera z) are dropped",
        type="number",
        exclusiveMinimum=0,
    )

    def kwargs(self) -> dict:
        """Keyword arguments for :func:`rasterize`."""
        return {f.name: getattr(self, f.name) for f in fields(self)}


def resolve_backend(backend: str, device: torch.device) -> str:
    """``auto`` -> ``gsplat`` on CUDA with gsplat installed, else ``native`` on CPU when the C++ kernels build
    (:func:`frng.render.native.available`), else ``torch``."""
    from frng.render import native  # not at import: `python -m frng.render.native` runs it as __main__

    if backend not in BACKENDS:
        raise ValueError(f"unknown raster backend {backend!r}; choose from {', '.join(BACKENDS)}")
    if backend == "auto":
        if device.type == "cuda" and gsplat_backend.available():
            return "gsplat"
        return "native" if device.type == "cpu" and native.available() else "torch"
    if backend == "gsplat" and not gsplat_backend.available():
        raise RuntimeError("raster backend 'gsplat' needs CUDA and the gsplat package; use 'torch' or 'auto'")
    if backend == "native" and (device.type != "cpu" or not native.available()):
        raise RuntimeError(
            "raster backend 'native' needs CPU tensors and the C++ kernels (see the warning); use 'torch' or 'auto'"
        )
    return backend


def rasterize(
    means: torch.Tensor,
    quats: torch.Tensor,
    scales: torch.Tensor,
    opacities: torch.Tensor,
    features: torch.Tensor,
    c2w: torch.Tensor,
    intrinsics: torch.Tensor,
    height: int,
    width: int,
    backend: str = "auto",
    tile_size: int = 4,
    chunk: int = 64,
    compile: bool = False,
    max_radius_px: float | None = None,
    min_transmittance: float = 1e-4,
    eps2d: float = 0.3,
    near: float = 0.01,
    far: float = 1e10,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Render N 3D Gaussians with C-channel features into V pinhole cameras (differentiable in all inputs
    except the cameras).

    Args:
        means: (N, 3) world-space centres.
        quats: (N, 4) rotations as quaternions (w, x, y, z); any norm (normalised here; zero -> identity).
        scales: (N, 3) standard deviations along the rotated axes (linear, not log; clamped at 0).
        opacities: (N,) in [0, 1].
        features: (N, C) shared by all views, or (V, N, C) per view (e.g. SH evaluated per view direction).
            Any C: RGB, radiance, 16-32-channel neural features.
        c2w: (V, 4, 4) OpenCV camera-to-world matrices (``frng.camera``).
        intrinsics: (V, 4) pinhole ``fx, fy, cx, cy`` in pixels.
        height, width: image size in pixels.
        backend: ``auto`` (gsplat on CUDA when installed, else ``native`` on CPU when it builds, else
            ``torch``), ``torch`` (tile-binned, pure PyTorch, any device), ``native`` (the same tile rasterizer
            with its binning and compositing in fused C++ CPU kernels, :mod:`frng.render.native`), ``gsplat``
            (CUDA), ``reference`` (brute force, tests only).
        tile_size, chunk, compile, min_transmittance: ``torch`` and ``native`` backends only: tile edge in pixels;
            ``torch`` only: Gaussians per depth chunk, ``torch.compile`` the compositing kernel; early-termination
            threshold (``torch``: a tile stops once all its pixels' transmittance is below it; ``native``: each
            pixel stops once its own is; 0 disables early termination).
        max_radius_px: footprints whose 3-sigma radius exceeds this are shrunk to it (None: no cap).
        eps2d: screen-space low-pass added to the 2D covariance diagonal (px^2), as 3DGS/gsplat.
        near, far: camera-z clipping; Gaussians outside are dropped (no NaN for points behind the camera).

    Returns:
        features (V, H, W, C): alpha-premultiplied sum of w_i f_i, w_i = alpha_i prod_{j<i} (1 - alpha_j),
            Gaussians in order of camera-z of their centres (composite over a background b with
            ``features + (1 - alpha) * b``);
        alpha (V, H, W, 1): sum of w_i = 1 - final transmittance;
        depth (V, H, W, 1): sum of w_i z_i (divide by alpha for the expected depth).
    """
    N = means.shape[0]
    if features.dim() not in (2, 3) or features.shape[-2] != N:
        raise ValueError(f"features must be (N, C) or (V, N, C) with N={N}, got {tuple(features.shape)}")
    name = resolve_backend(backend, means.device)
    common = dict(near=near, far=far, eps2d=eps2d)
    scene = (means, quats, scales, opacities, features, c2w, intrinsics, height, width)
    if name == "reference":
        return rasterize_reference(*scene, max_radius_px=max_radius_px, **common)
    if name == "gsplat":
        return gsplat_backend.rasterize_gsplat(*scene, **common)
    proj = project_gaussians(
        means, quats, scales, c2w, intrinsics, height, width, max_radius_px=max_radius_px, opacities=opacities, **common
    )
    return rasterize_tiles(
        proj,
        opacities,
        features,
        height,
        width,
        tile=tile_size,
        chunk=chunk,
        min_transmittance=min_transmittance,
        compile=compile,
        kernel=name,
    )
