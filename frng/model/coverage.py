"""Screen-space coverage of the rendered silhouette's rim (our addition; ``frng.coverage_head``, on by default).

The ground truth's silhouette is anti-aliased: Cycles' pixel filter leaves its outermost pixel ring part object,
part background. F-RNG's Gaussians sit on the backbone's visual hull, which seen from between the input views is
about a pixel wider than the object, and a splat rasterizer covers those rim pixels fully: the rim is the object's
colour where the ground truth mixes in the background (at the default tier's 96 px the ground truth's outermost
ring holds ~45 % of F-RNG's squared error; docs/model-and-training.md). The head learns the rim's coverage once per
rasterized view, before shading:

    rim    = covered pixels (alpha > ALPHA_MIN) with a pixel of alpha < 0.5 within RIM_PX (the render's silhouette)
    gain   = sigmoid(CNN([alpha, maps / alpha]) + GAIN_LOGIT) / sigmoid(GAIN_LOGIT)
    alpha' = min(alpha gain, 1) on the rim, alpha elsewhere;  maps' = maps alpha' / alpha (same features, less coverage)

``maps`` (V, H, W, C) is the rasterized alpha-premultiplied payload, ``alpha`` (V, H, W, 1) its coverage. The CNN
(two 3x3 convolutions and a 1x1 output that starts at zero: an untrained head keeps the rasterizer's coverage) is
trained by F-RNG's own losses. Restricted to the rim: applied to the whole foreground the same head learned to thin
the interior, brightening dark colours towards the background (a colour shortcut, not coverage).

It changes the silhouette, not the relighting: report the interior PSNR (the ladder's, without the 2-px rim) beside
the overall one when comparing against a method without it.
"""

from __future__ import annotations

import torch
from torch import nn
from torch.nn import functional as F

# below this coverage a pixel is background: its features are undefined and the head leaves it alone
ALPHA_MIN = 1e-3
# the gain's logit at a zero output: gain 1 there, at most 1 / sigmoid(GAIN_LOGIT) = 1.018
GAIN_LOGIT = 4.0
# the rim: covered pixels within this many pixels of one the render leaves (mostly) empty
RIM_PX = 1
# the key prefix of the head's weights beside the decoder's in an asset's decoder.safetensors (frng.apps.asset)
COVERAGE_PREFIX = "coverage."
# sigmoid(GAIN_LOGIT) in float32, computed once (the gain's normaliser)
_GAIN_NORM = float(torch.sigmoid(torch.tensor(GAIN_LOGIT)))


def silhouette_rim(alpha: torch.Tensor, px: int = RIM_PX) -> torch.Tensor:
    """alpha (V, H, W, 1) -> (V, H, W, 1) bool: covered pixels with a pixel of alpha < 0.5 within ``px``."""
    k = 2 * px + 1
    a_min = -F.max_pool2d(-alpha.detach().float().permute(0, 3, 1, 2), k, 1, px).permute(0, 2, 3, 1)
    return (alpha > ALPHA_MIN) & (a_min < 0.5)


class CoverageHead(nn.Module):
    """A small CNN from a rasterized view's coverage and normalized payload to a gain on its rim's alpha."""

    def __init__(self, channels: int, hidden: int):
        super().__init__()
        if hidden < 1:
            raise ValueError(f"CoverageHead: hidden must be >= 1, got {hidden}")
        self.channels = channels
        self.net = nn.Sequential(
            nn.Conv2d(channels + 1, hidden, 3, padding=1),
            nn.GELU(),
            nn.Conv2d(hidden, hidden, 3, padding=1),
            nn.GELU(),
            nn.Conv2d(hidden, 1, 1),
        )
        nn.init.zeros_(self.net[-1].weight)
        nn.init.zeros_(self.net[-1].bias)

    def forward(self, maps: torch.Tensor, alpha: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """maps (V, H, W, C) alpha-premultiplied payload, alpha (V, H, W, 1) -> (maps', alpha'), same shapes."""
        assert maps.dim() == 4 and maps.shape[-1] == self.channels, (maps.shape, self.channels)
        assert alpha.shape == maps.shape[:3] + (1,), (maps.shape, alpha.shape)
        fg, rim = alpha > ALPHA_MIN, silhouette_rim(alpha)
        a = alpha.float()
        feat = torch.where(fg, maps.float() / a.clamp_min(ALPHA_MIN), torch.zeros((), device=maps.device))
        x = torch.cat([a, feat], -1).permute(0, 3, 1, 2)
        r = self.net(x.to(self.net[0].weight.dtype)).permute(0, 2, 3, 1).float()
        gain = torch.sigmoid(r + GAIN_LOGIT) / _GAIN_NORM
        a_new = torch.where(rim, (a * gain).clamp(max=1.0), a)
        scale = torch.where(rim, a_new / a.clamp_min(ALPHA_MIN), torch.ones((), device=maps.device))
        return maps * scale.to(maps.dtype), a_new.to(alpha.dtype)


__all__ = ["ALPHA_MIN", "GAIN_LOGIT", "RIM_PX", "CoverageHead", "silhouette_rim"]
