"""The one error of capture input (:class:`CaptureError`), in a leaf module so that the capture's helpers
(:mod:`frng.apps.camera_formats`, :mod:`frng.apps.capture_frame`) and :mod:`frng.apps.capture` can all raise it
without importing each other."""

from __future__ import annotations


class CaptureError(ValueError):
    """Bad capture input (names the file at fault); nothing was written."""


__all__ = ["CaptureError"]
