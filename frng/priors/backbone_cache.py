"""Stage ``frng backbone-cache``: cache one object's backbone tokens and Gaussians (schema: :mod:`frng.priors.cache`)."""

from frng.priors.cache import configure_backbone as configure
from frng.priors.cache import run_backbone as run

__all__ = ["configure", "run"]
