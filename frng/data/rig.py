"""Camera rig of one object (no bpy): the paper's 6 input views, extra input views, random target views.

All cameras look at the origin (the object is normalised into the unit sphere there) from
``render.camera_distance`` with world Z up in the image, via :func:`frng.camera.look_at` (OpenCV c2w).

- Input views ``in_00 .. in_05``: front/back/left/right at 0 deg elevation (azimuths a0 + 0/90/180/270)
  and two at 45 deg elevation 180 deg apart (azimuths a0 + 45 and a0 + 225); ``a0`` is uniform in [0, 360).
- Extra input views ``in_06 ..`` (number-of-views sweep): same distribution -- uniform azimuth, elevation
  0 or 45 deg with equal probability.
- Target views ``tgt_000 ..``: uniform on the sphere (uniform azimuth, sin(elevation) uniform in [-1, 1]).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from frng import camera

RIG_ELEVATIONS_DEG = (0.0, 0.0, 0.0, 0.0, 45.0, 45.0)
RIG_AZIMUTH_OFFSETS_DEG = (0.0, 90.0, 180.0, 270.0, 45.0, 225.0)


@dataclass(frozen=True)
class View:
    """One camera. ``c2w`` is a (4, 4) OpenCV camera-to-world; ``intrinsics`` is (fx, fy, cx, cy) in pixels."""

    name: str
    kind: str  # "input" or "target"
    azimuth_deg: float
    elevation_deg: float
    c2w: np.ndarray
    intrinsics: np.ndarray
    width: int
    height: int

    def to_dict(self) -> dict:
        return {
            "name": self.name,
            "kind": self.kind,
            "azimuth_deg": round(self.azimuth_deg, 6),
            "elevation_deg": round(self.elevation_deg, 6),
            "c2w": self.c2w.tolist(),
            "intrinsics": self.intrinsics.tolist(),
            "width": self.width,
            "height": self.height,
        }

    @classmethod
    def from_record(cls, d: dict) -> View:
        """The view a :meth:`to_dict` record (a meta.json ``views`` entry) describes."""
        return cls(
            str(d["name"]),
            str(d["kind"]),
            float(d["azimuth_deg"]),
            float(d["elevation_deg"]),
            np.asarray(d["c2w"], dtype=np.float64).reshape(4, 4),
            np.asarray(d["intrinsics"], dtype=np.float64).reshape(4),
            int(d["width"]),
            int(d["height"]),
        )


def make_view(
    name: str, kind: str, azimuth_deg: float, elevation_deg: float, distance: float, fov_deg: float, resolution: int
) -> View:
    eye = camera.spherical_to_cartesian(azimuth_deg, elevation_deg, distance)
    return View(
        name,
        kind,
        float(azimuth_deg % 360.0),
        float(elevation_deg),
        camera.look_at(eye),
        camera.intrinsics_from_fov(fov_deg, resolution, resolution),
        resolution,
        resolution,
    )


def input_views(rng: np.random.Generator, n_extra: int, distance: float, fov_deg: float, resolution: int) -> list[View]:
    """The 6-view rig plus ``n_extra`` extra input views (names ``in_00 ..``)."""
    a0 = rng.uniform(0.0, 360.0)
    angles = [(a0 + off, el) for off, el in zip(RIG_AZIMUTH_OFFSETS_DEG, RIG_ELEVATIONS_DEG)]
    for _ in range(n_extra):
        angles.append((rng.uniform(0.0, 360.0), float(rng.choice([0.0, 45.0]))))
    return [
        make_view(f"in_{i:02d}", "input", az, el, distance, fov_deg, resolution) for i, (az, el) in enumerate(angles)
    ]


def target_views(rng: np.random.Generator, count: int, distance: float, fov_deg: float, resolution: int) -> list[View]:
    """``count`` views uniform on the sphere (names ``tgt_000 ..``)."""
    views = []
    for i in range(count):
        az = rng.uniform(0.0, 360.0)
        el = math.degrees(math.asin(rng.uniform(-1.0, 1.0)))
        views.append(make_view(f"tgt_{i:03d}", "target", az, el, distance, fov_deg, resolution))
    return views


def object_views(rng: np.random.Generator, render) -> tuple[list[View], list[View]]:
    """Input and target views of one object from the ``render`` config section
    (:class:`frng.plan.dataset_config.RenderConfig`)."""
    args = (render.camera_distance, render.fov_deg, render.resolution)
    inputs = input_views(rng, render.extra_input_views, *args)
    targets = target_views(rng, render.target_views, *args)
    return inputs, targets
