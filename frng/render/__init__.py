"""Rendering core: Gaussian rasterization (:func:`rasterize`), spherical harmonics (:mod:`frng.render.sh`),
deferred neural / GGX shading (:mod:`frng.render.shading`). Environment-light sampling lives in
:mod:`frng.envmap`."""

from frng.render.raster import RasterConfig, rasterize

__all__ = ["RasterConfig", "rasterize"]
