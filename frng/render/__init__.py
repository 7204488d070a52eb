"""Rendering core: Gaussian rasterization (:func:`rasterize`), spherical harmonics (:mod:`frng.render.sh`),
environment-map sampling (:mod:`frng.render.envmap`), deferred neural / GGX shading (:mod:`frng.render.shading`).

``rasterize`` and ``RasterConfig`` are loaded on first use (PEP 562), so that the torch-free parts (``envmap``,
imported by curation) do not import torch through this package."""

__all__ = ["RasterConfig", "rasterize"]


def __getattr__(name: str):
    if name in __all__:
        from frng.render import raster

        return getattr(raster, name)
    raise AttributeError(f"module 'frng.render' has no attribute {name!r}")
