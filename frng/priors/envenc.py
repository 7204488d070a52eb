"""Environment-map conditioning: a documented encoding of HDR equirect maps into light tokens.

RelitLRM (notes/relitlrm.md section 2) feeds the DiT 9 channels per env-map pixel: a log encoding for dark
regions, a hybrid-log-gamma (HLG) encoding for bright ones, and the pixel's direction. It leaves the handling
of E <= 1 and the HLG constants open; this module fixes them:

1. The map (any 2:1 size) is resized (area-averaged, :func:`torch.nn.functional.adaptive_avg_pool2d`) to
   ``height x 2*height`` (config ``backbone.env_height``), so every map gives the same number of tokens.
2. Per pixel, 10 channels:
   - ``E_log = log1p(E) / log1p(max E)``           (3, in [0, 1]; dark-region emphasis, defined for E = 0)
   - ``E_hlg = HLG(E / max E)``                    (3, in [0, 1]; ITU-R BT.2100 HLG OETF, bright regions)
   - ``log(mean E) / 4``                            (1, broadcast; the absolute intensity both others drop)
   - the pixel's unit direction (frng.render.envmap convention) (3)
3. Patchify (``backbone.env_patch``) -> Linear -> GeLU -> Linear gives tokens of the model width.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

from frng.nn import patchify
from frng.render import envmap

HLG_A, HLG_B, HLG_C = 0.17883277, 0.28466892, 0.55991073
ENV_CHANNELS = 10


def hlg(x: torch.Tensor) -> torch.Tensor:
    """ITU-R BT.2100 HLG OETF on [0, 1]."""
    x = x.clamp(0.0, 1.0)
    low = torch.sqrt(3.0 * x)
    high = HLG_A * torch.log((12.0 * x - HLG_B).clamp_min(1e-6)) + HLG_C
    return torch.where(x <= 1.0 / 12.0, low, high)


def encode(env: torch.Tensor, height: int) -> torch.Tensor:
    """HDR equirect maps (B, He, We, 3) -> encoded pixels (B, height, 2*height, 10)."""
    B = env.shape[0]
    e = F.adaptive_avg_pool2d(env.permute(0, 3, 1, 2).clamp_min(0.0), (height, 2 * height)).permute(0, 2, 3, 1)
    emax = e.amax(dim=(1, 2, 3), keepdim=True).clamp_min(1e-6)
    e_log = torch.log1p(e) / torch.log1p(emax)
    e_hlg = hlg(e / emax)
    w = envmap.pixel_solid_angles(height, 2 * height, device=env.device, dtype=env.dtype)
    mean = (e.mean(-1) * w).sum(dim=(1, 2)) / w.sum()
    level = (torch.log(mean.clamp_min(1e-6)) / 4.0).reshape(B, 1, 1, 1).expand(B, height, 2 * height, 1)
    dirs = envmap.pixel_directions(height, 2 * height, device=env.device, dtype=env.dtype)
    dirs = dirs.unsqueeze(0).expand(B, -1, -1, -1)
    return torch.cat([e_log, e_hlg, level, dirs], dim=-1)


class EnvTokenizer(nn.Module):
    """Env maps (B, He, We, 3) -> light tokens (B, (height/p) * (2*height/p), dim)."""

    def __init__(self, dim: int, height: int = 32, patch: int = 8):
        super().__init__()
        if height % patch:
            raise ValueError(f"env encoding height {height} is not a multiple of its patch size {patch}")
        self.height, self.patch = height, patch
        self.mlp = nn.Sequential(nn.Linear(patch * patch * ENV_CHANNELS, dim), nn.GELU(), nn.Linear(dim, dim))

    @property
    def num_tokens(self) -> int:
        return (self.height // self.patch) * (2 * self.height // self.patch)

    def forward(self, env: torch.Tensor) -> torch.Tensor:
        x = patchify(encode(env, self.height), self.patch)
        return self.mlp(x).flatten(1, 2)


def constant_env(height: int, value: float = 1.0, device=None) -> torch.Tensor:
    """A uniform white environment (H, 2H, 3): the documented stand-in when an input light is unknown."""
    return torch.full((height, 2 * height, 3), value, device=device)


__all__ = ["encode", "EnvTokenizer", "hlg", "constant_env", "ENV_CHANNELS"]
