"""Applications built on the libraries, beside the pipeline's stages: what a user runs to look at or use the results.

- :mod:`frng.apps.view`: ``frng view``, an interactive relighting viewer in the browser (viser), rendering a
  relightable asset (:mod:`frng.asset`) with the project's own rasterizer and decoder (:mod:`frng.render`).

An application renders through :mod:`frng.asset` and :mod:`frng.render` only, never the training code; its
``frng`` subcommand is a thin stage in :mod:`frng.stages` (argument parsing and error lines).
"""
