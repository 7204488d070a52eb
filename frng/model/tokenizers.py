"""IDM prior tokenizer (paper Sec. 4.1, the T_prior equation) and patchify/unpatchify helpers.

    T_prior_i = Tokenizer(Patchify(g_n, g_a, g_r, g_m))       a single linear layer over each 8x8 patch

The same tokenizer feeds the FineGeoDetokenizer (after bilinear interpolation) and MaterialFormer (paper Sec. 4.2.1:
"we use the same tokenizer for IDM priors as in Sec. 4.1"). Depth is an IDM output too but, as in the paper, the
prior tokens use normal (3), albedo (3), roughness (1), metallic (1) only -> 8 channels per pixel, in that order.

Patchify order (shared with :mod:`frng.nn` and the backbone's detokenizers): pixel (y, x) of a patch lands at flat
index ``(y * p + x) * C + c`` of the token's ``p*p*C`` vector.
"""

from __future__ import annotations

from collections.abc import Mapping

import torch
from torch import nn

from frng.nn import patchify, unpatchify

PRIOR_PASSES = (("normal", 3), ("albedo", 3), ("roughness", 1), ("metallic", 1))
PRIOR_CHANNELS = sum(c for _, c in PRIOR_PASSES)  # 8


def stack_priors(priors: Mapping[str, torch.Tensor]) -> torch.Tensor:
    """Dict of IDM passes -> (..., H, W, 8) in PRIOR_PASSES order.

    Each pass is (..., H, W, C) or, for the 1-channel ones, (..., H, W). Other keys (e.g. ``depth``) are ignored.
    """
    parts = []
    for name, c in PRIOR_PASSES:
        if name not in priors:
            raise KeyError(f"IDM priors lack the '{name}' pass (have {sorted(priors)})")
        t = priors[name]
        if c == 1 and (t.dim() < 3 or t.shape[-1] != 1):
            t = t.unsqueeze(-1)
        if t.shape[-1] != c:
            raise ValueError(f"IDM pass '{name}' has {t.shape[-1]} channels, expected {c}")
        parts.append(t)
    return torch.cat(parts, dim=-1)


class PriorTokenizer(nn.Module):
    """T_prior = Linear(Patchify(priors)): (..., H, W, 8) -> (..., H/p, W/p, dim).

    Inputs are used as the IDM gives them: normals in [-1, 1], albedo/roughness/metallic in [0, 1]; the layer's
    bias absorbs the offsets.
    """

    def __init__(self, dim: int, patch: int = 8, in_channels: int = PRIOR_CHANNELS):
        super().__init__()
        self.patch, self.in_channels, self.dim = patch, in_channels, dim
        self.proj = nn.Linear(patch * patch * in_channels, dim)

    def forward(self, priors: torch.Tensor) -> torch.Tensor:
        if priors.shape[-1] != self.in_channels:
            raise ValueError(f"PriorTokenizer expects {self.in_channels} channels, got {priors.shape[-1]}")
        H, W = priors.shape[-3], priors.shape[-2]
        if H % self.patch or W % self.patch:
            raise ValueError(f"priors {H}x{W} are not a multiple of the patch size {self.patch}")
        return self.proj(patchify(priors, self.patch))


__all__ = ["PRIOR_CHANNELS", "PRIOR_PASSES", "PriorTokenizer", "patchify", "stack_priors", "unpatchify"]
