"""The IDM prior tensors: one container shared by every IDM kind (learned, oracle, diffusion-renderer).

Per input view, per pixel (channels-last, float32):

=========== ============ =====================================================================================
name        shape        meaning
=========== ============ =====================================================================================
normal      (V, H, W, 3) world-space unit normal (Z up, the frng conventions); 0 on the background
depth       (V, H, W, 1) camera-frame z distance (OpenCV, world units); 0 on the background
albedo      (V, H, W, 3) linear base colour in [0, 1]; 0 on the background
roughness   (V, H, W, 1) [0, 1]; 0 on the background
metallic    (V, H, W, 1) [0, 1]; 0 on the background
mask        (V, H, W, 1) foreground mask in [0, 1] (the input views' alpha; the oracle's own coverage)
=========== ============ =====================================================================================

:meth:`IntrinsicPriors.stack` concatenates them in ``PASS_ORDER`` into (V, H, W, 12) for tokenizers;
F-RNG's prior tokenizer (paper section 3) uses normal, albedo, roughness, metallic (``TOKEN_PASSES``).
"""

from __future__ import annotations

from dataclasses import dataclass, fields

import torch

PASS_CHANNELS = {"normal": 3, "depth": 1, "albedo": 3, "roughness": 1, "metallic": 1, "mask": 1}
PASS_ORDER = tuple(PASS_CHANNELS)
TOKEN_PASSES = ("normal", "albedo", "roughness", "metallic")


@dataclass
class IntrinsicPriors:
    normal: torch.Tensor
    depth: torch.Tensor
    albedo: torch.Tensor
    roughness: torch.Tensor
    metallic: torch.Tensor
    mask: torch.Tensor

    def __post_init__(self):
        V, H, W = self.normal.shape[:3]
        for f in fields(self):
            t = getattr(self, f.name)
            want = (V, H, W, PASS_CHANNELS[f.name])
            if tuple(t.shape) != want:
                raise ValueError(f"IDM prior '{f.name}' has shape {tuple(t.shape)}, expected {want}")

    def as_dict(self) -> dict[str, torch.Tensor]:
        return {f.name: getattr(self, f.name) for f in fields(self)}

    @classmethod
    def from_dict(cls, d: dict[str, torch.Tensor]) -> IntrinsicPriors:
        missing = [k for k in PASS_ORDER if k not in d]
        if missing:
            raise KeyError(f"IDM priors lack pass(es) {missing}")
        return cls(**{k: d[k].float() for k in PASS_ORDER})

    def stack(self, passes: tuple[str, ...] = PASS_ORDER) -> torch.Tensor:
        """(V, H, W, sum of channels) in the given pass order."""
        return torch.cat([getattr(self, p) for p in passes], dim=-1)

    def masked(self) -> IntrinsicPriors:
        """Zero every pass outside the mask (mask > 0.5) -- the documented background convention."""
        fg = (self.mask > 0.5).float()
        d = {k: v * fg if k != "mask" else v for k, v in self.as_dict().items()}
        return IntrinsicPriors(**d)

    def select(self, views) -> IntrinsicPriors:
        return IntrinsicPriors(**{k: v[views] for k, v in self.as_dict().items()})

    def to(self, device) -> IntrinsicPriors:
        return IntrinsicPriors(**{k: v.to(device) for k, v in self.as_dict().items()})
