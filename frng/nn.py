"""Shared network building blocks: a Pre-LN transformer (GeLU MLP, fused SDPA attention) and patch (de)tokenizers.

Used by the backbone (GeoTransformer, appearance DiT), the IDM and F-RNG's MaterialFormer, so all of them
share one tested implementation. Tensors are channels-last: tokens (B, L, D).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
import torch.nn.functional as F
from torch import nn

from frng.plan.sections import key, register


@register("model")
@dataclass(frozen=True)
class ModelConfig:
    """The config's ``model`` section: the patch size of every tokenizer (each key declared on its field)."""

    patch_size: int = key(
        8,
        "patch size of every tokenizer (paper: 8; the default tier 12 at 96 px: 8 x 8 tokens per view); "
        "`render.resolution` must be a multiple",
        type="integer",
        minimum=1,
        maximum=256,
    )


class Attention(nn.Module):
    """Multi-head self-attention over (B, L, D) with torch's fused scaled_dot_product_attention."""

    def __init__(self, dim: int, heads: int):
        super().__init__()
        if dim % heads:
            raise ValueError(f"width {dim} is not divisible by {heads} heads")
        self.heads = heads
        self.qkv = nn.Linear(dim, 3 * dim)
        self.proj = nn.Linear(dim, dim)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        B, L, D = x.shape
        q, k, v = self.qkv(x).view(B, L, 3, self.heads, D // self.heads).permute(2, 0, 3, 1, 4)
        if q.dtype == torch.bfloat16 and q.device.type == "cpu":
            # CPU flash attention in bf16 is slower than in fp32 (fwd+bwd of (2, 4, 528, 32): 94 vs 63 ms per 4
            # layers on an AVX512-BF16 EPYC), so under autocast the projections run in bf16 and the attention in fp32
            with torch.autocast("cpu", enabled=False):
                y = F.scaled_dot_product_attention(q.float(), k.float(), v.float())
        else:
            y = F.scaled_dot_product_attention(q, k, v)
        return self.proj(y.transpose(1, 2).reshape(B, L, D))


class Block(nn.Module):
    """Pre-LN transformer block: x + Attn(LN(x)); x + MLP(LN(x)) with a GeLU MLP (ratio 4)."""

    def __init__(self, dim: int, heads: int, mlp_ratio: float = 4.0):
        super().__init__()
        self.norm1 = nn.LayerNorm(dim)
        self.attn = Attention(dim, heads)
        self.norm2 = nn.LayerNorm(dim)
        hidden = int(dim * mlp_ratio)
        self.mlp = nn.Sequential(nn.Linear(dim, hidden), nn.GELU(), nn.Linear(hidden, dim))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        x = x + self.attn(self.norm1(x))
        return x + self.mlp(self.norm2(x))


class Transformer(nn.Module):
    """A stack of Pre-LN blocks with a final LayerNorm. (B, L, D) -> (B, L, D)."""

    def __init__(self, dim: int, depth: int, heads: int, mlp_ratio: float = 4.0):
        super().__init__()
        self.blocks = nn.ModuleList([Block(dim, heads, mlp_ratio) for _ in range(depth)])
        self.norm = nn.LayerNorm(dim)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        for block in self.blocks:
            x = block(x)
        return self.norm(x)


def patchify(images: torch.Tensor, p: int) -> torch.Tensor:
    """(..., H, W, C) -> (..., H/p, W/p, p*p*C); pixel (y, x) of a patch lands at index (y*p + x)*C + c."""
    *lead, H, W, C = images.shape
    x = images.reshape(*lead, H // p, p, W // p, p, C)
    n = len(lead)
    x = x.permute(*range(n), n, n + 2, n + 1, n + 3, n + 4)
    return x.reshape(*lead, H // p, W // p, p * p * C)


def unpatchify(tokens: torch.Tensor, p: int, channels: int) -> torch.Tensor:
    """Inverse of :func:`patchify`: (..., h, w, p*p*C) -> (..., h*p, w*p, C)."""
    *lead, h, w, _ = tokens.shape
    x = tokens.reshape(*lead, h, w, p, p, channels)
    n = len(lead)
    x = x.permute(*range(n), n, n + 2, n + 1, n + 3, n + 4)
    return x.reshape(*lead, h * p, w * p, channels)


class PatchTokenizer(nn.Module):
    """Linear patch embedding (a stride-p convolution): images (..., H, W, C) -> tokens (..., H/p, W/p, D)."""

    def __init__(self, in_channels: int, dim: int, patch: int):
        super().__init__()
        self.patch = patch
        self.proj = nn.Linear(patch * patch * in_channels, dim)

    def forward(self, images: torch.Tensor) -> torch.Tensor:
        return self.proj(patchify(images, self.patch))


class PatchDetokenizer(nn.Module):
    """LayerNorm + a single linear layer from a token to p*p per-pixel vectors: (..., h, w, D) -> (..., H, W, C)."""

    def __init__(self, dim: int, out_channels: int, patch: int):
        super().__init__()
        self.patch, self.out_channels = patch, out_channels
        self.norm = nn.LayerNorm(dim)
        self.proj = nn.Linear(dim, patch * patch * out_channels)

    def forward(self, tokens: torch.Tensor) -> torch.Tensor:
        return unpatchify(self.proj(self.norm(tokens)), self.patch, self.out_channels)


def timestep_embedding(t: torch.Tensor, dim: int, max_period: float = 10000.0) -> torch.Tensor:
    """DiT-style sinusoidal embedding of (B,) timesteps -> (B, dim)."""
    half = dim // 2
    freqs = torch.exp(-math.log(max_period) * torch.arange(half, device=t.device, dtype=torch.float32) / half)
    args = t.float()[:, None] * freqs[None]
    emb = torch.cat([torch.cos(args), torch.sin(args)], dim=-1)
    if dim % 2:
        emb = torch.cat([emb, torch.zeros_like(emb[:, :1])], dim=-1)
    return emb


def count_parameters(module: nn.Module) -> int:
    return sum(p.numel() for p in module.parameters())
