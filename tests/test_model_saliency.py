"""Saliency map and top-K patch selection (supplement "Saliency map computation")."""

import math

import pytest
import torch

from frng.model.saliency import (
    SaliencyConfig,
    boundary_weight,
    local_std,
    num_selected,
    patch_scores,
    saliency_map,
    salient_patches,
    select_top_k,
)
from frng.plan.sections import ConfigError


def textured_square(size=64, lo=16, hi=48, seed=0):
    """RGBA view: a square with a fine checker texture (contrast +-0.15 around 0.5) on a black background."""
    g = torch.Generator().manual_seed(seed)
    img = torch.zeros(size, size, 4)
    yy, xx = torch.meshgrid(torch.arange(size), torch.arange(size), indexing="ij")
    checker = ((yy // 2 + xx // 2) % 2).float()
    tex = 0.5 + 0.3 * (checker - 0.5) + 0.02 * torch.rand(size, size, generator=g)
    inside = (yy >= lo) & (yy < hi) & (xx >= lo) & (xx < hi)
    img[..., :3] = (tex * inside).unsqueeze(-1)
    img[..., 3] = inside.float()
    return img


def test_silhouette_suppressed():
    img = textured_square()[None]  # (1, 64, 64, 4), square covers patches 2..5
    cfg = SaliencyConfig.from_dict({})
    s = saliency_map(img, cfg=cfg)
    raw = local_std(img[..., :3].mean(-1).clamp(0, 1) ** (1 / 2.2), cfg.box_size)  # S_raw, no suppression
    scores = patch_scores(s, 8)[0]
    raw_scores = patch_scores(raw, 8)[0]
    border = torch.cat([scores[2, 2:6], scores[5, 2:6], scores[3:5, 2], scores[3:5, 5]])
    interior = scores[3:5, 3:5].flatten()
    # without suppression the silhouette dominates; with it every interior patch beats every border patch
    raw_border = torch.cat([raw_scores[2, 2:6], raw_scores[5, 2:6]])
    assert raw_border.min() > raw_scores[3:5, 3:5].max()
    assert interior.min() > border.max()
    # the background and the silhouette pixels themselves score ~0
    assert s[0, :14].abs().max() < 1e-3 and s[0, 16, 16:48].abs().max() < 1e-3
    # selection picks interior patches
    idx = salient_patches(
        img, patch=8, cfg=SaliencyConfig.from_dict({"top_k": 0.04})
    )  # ceil(2.56) = 3 of the 4 interior ones
    rows, cols = idx // 8, idx % 8
    assert idx.shape == (1, 3) and ((rows >= 3) & (rows <= 4) & (cols >= 3) & (cols <= 4)).all()


def test_boundary_weight_monotone_and_mask_sources():
    mask = torch.zeros(1, 40, 40, dtype=torch.bool)
    mask[0, 5:35, 5:35] = True
    w = boundary_weight(mask, SaliencyConfig.from_dict({"sigma": 0.0}))
    row = w[0, 20, 5:21]
    assert row[0] == 0 and row[-1] == 1 and (row[1:] >= row[:-1]).all()
    # no background -> no suppression; explicit mask overrides alpha
    torch.testing.assert_close(
        boundary_weight(torch.ones(1, 8, 8, dtype=torch.bool), SaliencyConfig.from_dict({})), torch.ones(1, 8, 8)
    )
    img = textured_square(32, 8, 24)[None]
    a = saliency_map(img)
    b = saliency_map(img[..., :3], mask=img[..., 3])
    torch.testing.assert_close(a, b)


@pytest.mark.parametrize("k", [0.01, 0.02, 0.04, 0.07, 0.08, 0.5, 1.0])
@pytest.mark.parametrize("hw", [(4, 4), (8, 8), (10, 10), (64, 64)])
def test_top_k_exact_count(k, hw):
    h, w = hw
    V = 3
    scores = torch.rand(V, h, w)
    scores[1] = 0.5  # all ties in one view
    idx = select_top_k(scores, k)
    n = math.ceil(round(k * h * w, 6))
    assert idx.shape == (V, n)
    for v in range(V):
        assert len(set(idx[v].tolist())) == n  # distinct
        chosen = scores[v].flatten()[idx[v]]
        rest = torch.ones(h * w, dtype=torch.bool)
        rest[idx[v]] = False
        if rest.any():
            assert chosen.min() >= scores[v].flatten()[rest].max()
    assert num_selected(0.07, 100) == 7 and num_selected(0.02, 64) == 2 and num_selected(0.0, 64) == 0


def test_config_validation():
    with pytest.raises(ValueError):
        SaliencyConfig.from_dict({"box_size": 4})
    with pytest.raises(ValueError):
        SaliencyConfig.from_dict({"top_k": 2.0})
    assert SaliencyConfig.from_dict({"box_size": 7}).effective_margin == 4.0
    with pytest.raises(ConfigError, match=r"frng\.saliency\.unknown: unknown key"):  # strict: no key is dropped
        SaliencyConfig.from_dict({"box_size": 7, "unknown": 1})
