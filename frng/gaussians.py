"""Per-pixel Gaussian decoding shared by the backbone and F-RNG (paper "Preliminaries", Eq. 2; notes/relitlrm.md §1).

RelitLRM's GeoDetokenizer maps every geometry token to ``p*p`` raw 9-vectors, one Gaussian per pixel (F-RNG's
FineGeoDetokenizer does the same per fine token, one Gaussian per sub-pixel). The raw vector is split as
``[distance 1, scale 3, rotation 4, opacity 1]`` and decoded along that Gaussian's camera ray ``(o, d)``::

    w        = sigmoid(distance)
    centre   = o + d * (near * (1 - w) + far * w)        distance along the unit ray, bounded in [near, far]
    scale    = min(exp(raw_scale - SCALE_OFFSET), SCALE_MAX)
    rotation = raw_rot / |raw_rot|                       unit quaternion (w, x, y, z), gsplat's convention
    opacity  = sigmoid(raw_opacity - OPACITY_OFFSET)

Units. Objects live in the unit sphere and cameras sit ~2.6 from the origin (``render.camera_distance``), so the
object's depth range is about [1.6, 3.6]; ``near``/``far`` default to the backbone's (1.0, 4.5), a margin around it.
RelitLRM's constants (offset 2.3, clamp 0.3, opacity offset 2.0) were chosen for objects in [-1, 1]^3 viewed from a
similar distance, so they are kept as they are: a raw scale of 0 gives 0.1 (5% of the object's diameter, ~2.6 px at
64 px / 50 deg FOV, ~21 px at 512), the clamp 0.3 stops single splats from covering the object, and a raw opacity
of 0 gives 0.12. They are named constants and :class:`GaussianDecodeConfig` fields so a different backbone can change
them; the fine-grained Gaussians use a larger scale offset (see :mod:`frng.model.fine_geometry`).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, fields

import torch

from frng import camera
from frng.plan.sections import Settings

RAW_CHANNELS = 9  # distance 1, scale 3, rotation 4, opacity 1
RAW_SPLIT = (1, 3, 4, 1)
SCALE_OFFSET = 2.3  # scale = exp(raw - SCALE_OFFSET): raw 0 -> 0.1 world units
SCALE_MAX = 0.3  # clamp on every scale axis (world units; the object's radius is 1)
OPACITY_OFFSET = 2.0  # opacity = sigmoid(raw - OPACITY_OFFSET): raw 0 -> 0.12
NEAR = 1.0  # default ray-distance bounds (the backbone's), cameras ~2.6 from a unit-sphere object
FAR = 4.5


@dataclass
class GaussianDecodeConfig(Settings):
    """Constants of the raw -> Gaussian decoding (RelitLRM's values by default)."""

    near: float = NEAR
    far: float = FAR
    scale_offset: float = SCALE_OFFSET
    scale_max: float = SCALE_MAX
    opacity_offset: float = OPACITY_OFFSET


def decode_raw(
    raw: torch.Tensor,
    origins: torch.Tensor,
    directions: torch.Tensor,
    cfg: GaussianDecodeConfig | None = None,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    """Raw parameters -> Gaussian attributes, element-wise over leading dims ``...``.

    raw: (..., 9); origins, directions: (..., 3) world-space rays with unit directions.
    Returns means (..., 3), quats (..., 4) unit (w, x, y, z), scales (..., 3), opacities (...).
    """
    cfg = cfg or GaussianDecodeConfig()
    if raw.shape[-1] != RAW_CHANNELS:
        raise ValueError(f"raw Gaussian parameters need {RAW_CHANNELS} channels, got {raw.shape[-1]}")
    dist, scale, rot, opac = raw.split(RAW_SPLIT, dim=-1)
    w = torch.sigmoid(dist)
    t = cfg.near * (1.0 - w) + cfg.far * w
    means = origins + directions * t
    scales = torch.exp(scale - cfg.scale_offset).clamp(max=cfg.scale_max)
    norm = rot.norm(dim=-1, keepdim=True)
    identity = torch.zeros_like(rot)
    identity[..., 0] = 1.0
    quats = torch.where(norm > 1e-8, rot / norm.clamp_min(1e-8), identity)  # a zero quaternion -> identity
    opacities = torch.sigmoid(opac - cfg.opacity_offset).squeeze(-1)
    return means, quats, scales, opacities


@dataclass
class Gaussians:
    """A flat set of N 3D Gaussians (one object). All tensors share N and the device.

    means (N, 3) world positions; quats (N, 4) unit quaternions (w, x, y, z); scales (N, 3) standard deviations
    along the rotated axes; opacities (N,) in (0, 1); features (N, ...) optional per-Gaussian payload (SH
    coefficients, neural material features, Cook-Torrance parameters).
    """

    means: torch.Tensor
    quats: torch.Tensor
    scales: torch.Tensor
    opacities: torch.Tensor
    features: torch.Tensor | None = None

    def __post_init__(self):
        n = self.means.shape[0]
        for f in fields(self):
            t = getattr(self, f.name)
            if t is not None and t.shape[0] != n:
                raise ValueError(f"Gaussians.{f.name} has {t.shape[0]} rows, means has {n}")

    def __len__(self) -> int:
        return self.means.shape[0]

    def __getitem__(self, index) -> Gaussians:
        """Index rows (slice, long indices or a bool mask of shape (N,))."""
        return Gaussians(
            **{f.name: None if getattr(self, f.name) is None else getattr(self, f.name)[index] for f in fields(self)}
        )

    def with_features(self, features: torch.Tensor | None) -> Gaussians:
        return Gaussians(self.means, self.quats, self.scales, self.opacities, features)

    def to(self, *args, **kwargs) -> Gaussians:
        return Gaussians(
            **{
                f.name: None if getattr(self, f.name) is None else getattr(self, f.name).to(*args, **kwargs)
                for f in fields(self)
            }
        )

    def detach(self) -> Gaussians:
        return Gaussians(
            **{f.name: None if getattr(self, f.name) is None else getattr(self, f.name).detach() for f in fields(self)}
        )

    @staticmethod
    def cat(parts: Sequence[Gaussians]) -> Gaussians:
        """Concatenate along N (e.g. coarse + fine Gaussians). Features must be all present or all absent."""
        parts = list(parts)
        if not parts:
            raise ValueError("Gaussians.cat needs at least one set")
        has = [p.features is not None for p in parts]
        if any(has) and not all(has):
            raise ValueError("Gaussians.cat: some sets have features and some do not")
        return Gaussians(
            means=torch.cat([p.means for p in parts]),
            quats=torch.cat([p.quats for p in parts]),
            scales=torch.cat([p.scales for p in parts]),
            opacities=torch.cat([p.opacities for p in parts]),
            features=torch.cat([p.features for p in parts]) if all(has) else None,
        )


def decode(
    raw: torch.Tensor,
    origins: torch.Tensor,
    directions: torch.Tensor,
    cfg: GaussianDecodeConfig | None = None,
    features: torch.Tensor | None = None,
) -> Gaussians:
    """Like :func:`decode_raw` but flattens all leading dims into N and returns :class:`Gaussians`.

    raw (..., 9), origins/directions (..., 3), features (..., F) or None -> Gaussians with N = prod(...).
    """
    means, quats, scales, opacities = decode_raw(raw, origins, directions, cfg)
    feats = None if features is None else features.reshape(means[..., 0].numel(), *features.shape[raw.dim() - 1 :])
    return Gaussians(means.reshape(-1, 3), quats.reshape(-1, 4), scales.reshape(-1, 3), opacities.reshape(-1), feats)


def isotropic_raw(
    distance: torch.Tensor,
    alpha: torch.Tensor,
    fx: torch.Tensor,
    footprint_px: float,
    cfg: GaussianDecodeConfig | None = None,
) -> torch.Tensor:
    """The raw 9-vectors that :func:`decode_raw` turns into isotropic per-pixel Gaussians: distance ``distance``
    along each pixel ray (clamped inside [near, far]), standard deviation ``footprint_px`` pixels at that distance,
    identity rotation, opacity = alpha clamped to [0.02, 0.98].

    distance, alpha (V, H, W, 1); fx (V,) focal lengths in pixels -> raw (V, H, W, 9)."""
    cfg = cfg or GaussianDecodeConfig()
    w = ((distance - cfg.near) / (cfg.far - cfg.near)).clamp(1e-3, 1 - 1e-3)
    scale = (distance * footprint_px / fx.reshape(-1, 1, 1, 1)).clamp_min(1e-6)
    lead = distance.shape[:-1]
    return torch.cat(
        [
            torch.logit(w),
            (scale.log() + cfg.scale_offset).expand(*lead, 3),
            torch.ones_like(distance),
            torch.zeros_like(distance).expand(*lead, 3),
            torch.logit(alpha.clamp(0.02, 0.98)) + cfg.opacity_offset,
        ],
        dim=-1,
    )


def pixel_gaussians(
    raw: torch.Tensor,
    c2w: torch.Tensor,
    intrinsics: torch.Tensor,
    cfg: GaussianDecodeConfig | None = None,
    features: torch.Tensor | None = None,
) -> Gaussians:
    """The backbone's per-pixel Gaussians of one object: one Gaussian on every pixel-centre ray.

    raw: (V, H, W, 9) (the GeoDetokenizer's output); c2w: (V, 4, 4); intrinsics: (V, 4);
    features: (V, H, W, F) or None. Returns Gaussians with N = V*H*W in (view, row, col) order.
    """
    V, H, W, _ = raw.shape
    o, d = camera.pixel_rays(c2w.float(), intrinsics.float(), H, W)  # geometry in fp32 even under autocast
    return decode(raw.float(), o, d, cfg, features)


__all__ = [
    "FAR",
    "NEAR",
    "OPACITY_OFFSET",
    "RAW_CHANNELS",
    "RAW_SPLIT",
    "SCALE_MAX",
    "SCALE_OFFSET",
    "GaussianDecodeConfig",
    "Gaussians",
    "decode",
    "decode_raw",
    "isotropic_raw",
    "pixel_gaussians",
]
