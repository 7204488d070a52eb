"""frng.nn's attention: under CPU bf16 autocast the projections run in bf16 and the attention itself in fp32 (the CPU
flash kernel is slower in bf16, docs/performance.md), with gradients to every weight."""

import torch
import torch.nn.functional as F

from frng.nn import Attention, Transformer


def _spy_sdpa(monkeypatch) -> list[torch.dtype]:
    seen: list[torch.dtype] = []
    real = F.scaled_dot_product_attention

    def spy(q, k, v, *a, **kw):
        seen.append(q.dtype)
        return real(q, k, v, *a, **kw)

    monkeypatch.setattr(F, "scaled_dot_product_attention", spy)
    return seen


def test_cpu_autocast_runs_the_attention_in_fp32(monkeypatch):
    torch.manual_seed(0)
    attn = Attention(32, 4)
    x = torch.randn(2, 50, 32)
    seen = _spy_sdpa(monkeypatch)
    with torch.autocast("cpu", dtype=torch.bfloat16):
        y = attn(x)
    assert seen == [torch.float32]
    assert y.dtype == torch.bfloat16  # the output projection still runs under autocast
    ref = attn(x)  # fp32 throughout
    assert seen == [torch.float32, torch.float32]
    assert torch.allclose(y.float(), ref, atol=3e-2, rtol=3e-2), (y.float() - ref).abs().max()


def test_autocast_transformer_trains_every_weight():
    torch.manual_seed(0)
    model = Transformer(32, 2, 4, 4.0)
    x = torch.randn(1, 20, 32, requires_grad=True)
    with torch.autocast("cpu", dtype=torch.bfloat16):
        out = model(x)
    out.float().square().mean().backward()
    assert x.grad is not None and torch.isfinite(x.grad).all()
    for name, p in model.named_parameters():
        assert p.grad is not None and torch.isfinite(p.grad).all(), name
        assert p.grad.dtype == torch.float32, name
