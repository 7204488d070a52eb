"""Stage ``frng idm-priors``: one object's IDM priors for all its input views (schema: :mod:`frng.priors.cache`)."""

from frng.priors.cache import configure_idm as configure
from frng.priors.cache import run_idm as run

__all__ = ["configure", "run"]
