"""Intrinsic decomposition models (IDMs): per-pixel normal, depth, albedo, roughness, metallic per input view.

Three kinds, chosen by ``idm.kind`` and produced through :func:`frng.priors.build_idm` (the registry):

- ``learned`` (default) -- :class:`LearnedIDM`, a small transformer over ALL input views at once (one token
  sequence, so attention runs across views: the multi-view analogue of feeding DiffusionRenderer a video).
  Per view: [diffusion-space RGB (3), alpha (1), Pluecker rays (6)] -> 8x8 patches -> tokens; Pre-LN transformer
  (frng.nn); a linear patch detokenizer to ``pixel_features`` per pixel, then a per-pixel MLP over those features
  and the pixel's own RGB/alpha (keeps sub-patch detail) -> 9 raw values per pixel:

  ====== ======= ==========================================================================================
  raw    pass    decoding
  ====== ======= ==========================================================================================
  0:3    normal  unit-normalised, CAMERA frame (OpenCV), rotated to world with the view's c2w
  3      depth   near + sigmoid(raw) * (far - near)   (camera z)
  4:7    albedo  sigmoid
  7      rough.  sigmoid
  8      metal.  sigmoid
  ====== ======= ==========================================================================================

  Trained on the training split's G-buffers (``frng idm-train``), masked to the foreground:
  ``(1 - cos(n, n*)) + |depth_n - depth_n*| + |albedo - albedo*| + |rough - rough*| + |metal - metal*|``
  with depth normalised to [0, 1] over [near, far]. Then frozen.
- ``oracle`` -- the rendered G-buffers themselves (analysis / upper bound): :func:`oracle_priors`.
- ``diffusion-renderer`` -- DiffusionRenderer inverse-rendering output files: :mod:`frng.priors.diffusion_renderer`.

Every kind returns :class:`frng.priors.intrinsics.IntrinsicPriors` (shapes and conventions documented there).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import torch
import torch.nn.functional as F
from torch import nn

from frng import camera
from frng.nn import PatchDetokenizer, PatchTokenizer, Transformer
from frng.priors.diffusion import to_diffusion_space
from frng.priors.intrinsics import IntrinsicPriors

RAW_CHANNELS = 9


@dataclass
class IDMConfig:
    """Architecture of the learned IDM (``idm`` config section)."""

    width: int = 128
    heads: int = 4
    depth: int = 4
    patch: int = 8
    pixel_features: int = 16
    near: float = 1.0
    far: float = 4.5

    @classmethod
    def from_dict(cls, d: dict) -> "IDMConfig":
        return cls(**{k: v for k, v in d.items() if k in cls.__dataclass_fields__})

    def to_dict(self) -> dict:
        return asdict(self)


class LearnedIDM(nn.Module):
    """Multi-view IDM. See the module docstring."""

    def __init__(self, cfg: IDMConfig):
        super().__init__()
        self.cfg = cfg
        D, p = cfg.width, cfg.patch
        self.tokenizer = PatchTokenizer(3 + 1 + 6, D, p)
        self.view_embed = nn.Parameter(torch.zeros(D))
        self.transformer = Transformer(D, cfg.depth, cfg.heads)
        self.detokenizer = PatchDetokenizer(D, cfg.pixel_features, p)
        hidden = 2 * cfg.pixel_features
        self.pixel_head = nn.Sequential(
            nn.Linear(cfg.pixel_features + 4, hidden), nn.GELU(), nn.Linear(hidden, RAW_CHANNELS)
        )

    def forward(self, images: torch.Tensor, alpha: torch.Tensor, c2w: torch.Tensor, intr: torch.Tensor) -> torch.Tensor:
        """images (B, V, H, W, 3) linear premultiplied RGB; alpha (B, V, H, W, 1); c2w (B, V, 4, 4);
        intr (B, V, 4). Returns raw predictions (B, V, H, W, 9)."""
        B, V, H, W, _ = images.shape
        with torch.autocast(device_type=images.device.type, enabled=False):  # ray geometry in fp32
            o, d = camera.pixel_rays(c2w.reshape(B * V, 4, 4).float(), intr.reshape(B * V, 4).float(), H, W)
            rays = camera.plucker(o, d).reshape(B, V, H, W, 6)
        rgb = to_diffusion_space(images)
        a = 2.0 * alpha - 1.0
        tok = self.tokenizer(torch.cat([rgb, a, rays], dim=-1))  # (B, V, h, w, D)
        _, _, h, w, D = tok.shape
        x = self.transformer(tok.reshape(B, V * h * w, D)).reshape(B, V, h, w, D)
        feat = self.detokenizer(x)  # (B, V, H, W, F)
        return self.pixel_head(torch.cat([feat, rgb, a], dim=-1))

    def decode(self, raw: torch.Tensor, alpha: torch.Tensor, c2w: torch.Tensor) -> dict[str, torch.Tensor]:
        """raw (B, V, H, W, 9) -> dict of passes (B, V, H, W, C) in world space (not yet masked)."""
        c = self.cfg
        n_cam = F.normalize(raw[..., 0:3].float(), dim=-1, eps=1e-6)
        R = c2w[:, :, None, None, :3, :3]  # (B, V, 1, 1, 3, 3)
        normal = (R @ n_cam.unsqueeze(-1)).squeeze(-1)
        return {
            "normal": normal,
            "depth": c.near + torch.sigmoid(raw[..., 3:4]) * (c.far - c.near),
            "albedo": torch.sigmoid(raw[..., 4:7]),
            "roughness": torch.sigmoid(raw[..., 7:8]),
            "metallic": torch.sigmoid(raw[..., 8:9]),
            "mask": alpha,
        }

    @torch.no_grad()
    def predict(self, images: torch.Tensor, alpha: torch.Tensor, c2w: torch.Tensor, intr: torch.Tensor) -> IntrinsicPriors:
        """One object's views: images (V, H, W, 3), alpha (V, H, W, 1), c2w (V, 4, 4), intr (V, 4)."""
        raw = self(images[None], alpha[None], c2w[None], intr[None])
        out = self.decode(raw, alpha[None], c2w[None])
        return IntrinsicPriors(**{k: v[0].float() for k, v in out.items()}).masked()


def idm_loss(model: LearnedIDM, raw: torch.Tensor, alpha: torch.Tensor, c2w: torch.Tensor, target: dict) -> dict:
    """Masked per-pass losses. target: dict of G-buffer passes (B, V, H, W, C) in the IntrinsicPriors conventions.

    Returns a dict of scalar tensors (``normal``, ``depth``, ``albedo``, ``roughness``, ``metallic``, ``total``).
    The mask is the G-buffer coverage (``target['mask']`` > 0.5)."""
    pred = model.decode(raw, alpha, c2w)
    fg = (target["mask"] > 0.5).float()
    denom = fg.sum().clamp_min(1.0)
    c = model.cfg

    def l1(a, b):
        return ((a - b).abs().mean(-1, keepdim=True) * fg).sum() / denom

    losses = {
        "normal": ((1.0 - (pred["normal"] * target["normal"]).sum(-1, keepdim=True)) * fg).sum() / denom,
        "depth": l1((pred["depth"] - c.near) / (c.far - c.near), (target["depth"] - c.near) / (c.far - c.near)),
        "albedo": l1(pred["albedo"], target["albedo"]),
        "roughness": l1(pred["roughness"], target["roughness"]),
        "metallic": l1(pred["metallic"], target["metallic"]),
    }
    losses["total"] = sum(losses.values())
    return losses


def build(cfg: dict | IDMConfig) -> LearnedIDM:
    if isinstance(cfg, dict):
        cfg = IDMConfig.from_dict(cfg)
    return LearnedIDM(cfg)
