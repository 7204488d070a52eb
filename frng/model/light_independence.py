"""Light-independence regularization (paper Sec. 4.2.2, the L_ind equation; weights from the supplement).

    L_ind = lambda_c * C(T_mat_i, T_mat_i1) + lambda_KLD * L_KLD(T_mat_i, T_mat_i1)

T_mat_i and T_mat_i1 are MaterialFormer's output tokens for the same object and the same token positions (coarse
and fine), computed from the backbone's appearance tokens under the input light and under an extra random light
E1 (same T_geo, same T_prior, same salient-patch selection).

Our model also carries material past T_mat: the pixel head (:class:`frng.model.pixel_head.PixelHead`) gives every
Gaussian its input pixel's colour divided by the input light's irradiance. At this project's token widths that
per-pixel path carries most of the material, and it sees the photographs, not T_app; a loss on T_mat alone is then
met almost for free (measured: ~1e-6 after 100 steps, and w/o L_ind scored the same as the full model). With
``pixels`` (config ``train.loss.ind_pixels``, default on) the second pass also rebuilds that payload from the same
input views photographed under the object's second input light (curated data: ``render.input_lights`` >= 2), and
each term adds its value on the two per-Gaussian payloads (N, F), what the renderer reads (decoder features, or the
Cook-Torrance ablation's decoded GGX parameters, not its logits): shadows and highlights baked into the photos are
what differs, so the term asks the pixel head to take them out.

Exact definitions (the paper names the terms only):

- Cosine term: the paper's C is a similarity; as a loss we use the dissimilarity
  ``C = mean over tokens of (1 - cos(T_mat_i[t], T_mat_i1[t]))`` with the cosine taken over the channel dimension.
  Range [0, 2]; 0 iff every pair of tokens is parallel.
- KL term: each token becomes a categorical distribution over its channels, ``P[t] = softmax(T_mat_i[t] / tau)``
  and ``Q[t] = softmax(T_mat_i1[t] / tau)`` (temperature ``tau``, default 1; T_mat is the output of a LayerNorm, so
  its channels are O(1) and tau = 1 gives neither one-hot nor uniform distributions). Neither light is privileged,
  so the KL is symmetrised: ``L_KLD = mean over tokens of 0.5 * (KL(P||Q) + KL(Q||P))``. 0 iff the softmaxes agree.
- Both sides carry gradients (no stop-gradient); both terms are computed in float32 (also under bf16 autocast) and
  averaged over all tokens of all objects in the batch.

Together the terms vanish only when the tokens agree in direction (cosine) and in their relative channel profile
(KL): for identical inputs L_ind = 0, otherwise L_ind > 0. The paper's weights are (lambda_c, lambda_KLD,
lambda_1, lambda_per) = (0.2, 0.2, 1.0, 0.5); lambda_1/lambda_per weight the rendering losses (training code).
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
import torch.nn.functional as F

from frng.plan.sections import Settings


@dataclass
class LightIndependenceConfig(Settings):
    """Weights and temperature of L_ind (proposed config section ``model.loss`` / ``train.loss``)."""

    lambda_c: float = 0.2
    lambda_kld: float = 0.2
    temperature: float = 1.0
    pixels: bool = True  # also compare the per-Gaussian material rebuilt from the re-lit input views

    def __post_init__(self):
        if self.temperature <= 0:
            raise ValueError("light-independence temperature must be > 0")


def _check(a: torch.Tensor, b: torch.Tensor) -> None:
    if a.shape != b.shape:
        raise ValueError(f"material tokens differ in shape: {tuple(a.shape)} vs {tuple(b.shape)}")


def cosine_term(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """mean(1 - cos) over tokens. a, b: (..., C) material tokens -> scalar."""
    _check(a, b)
    cos = F.cosine_similarity(a.float(), b.float(), dim=-1, eps=1e-8)
    return (1.0 - cos).clamp_min(0.0).mean()


def kld_term(a: torch.Tensor, b: torch.Tensor, temperature: float = 1.0) -> torch.Tensor:
    """Symmetric KL between per-token channel softmaxes. a, b: (..., C) -> scalar (mean over tokens)."""
    _check(a, b)
    lp = F.log_softmax(a.float() / temperature, dim=-1)
    lq = F.log_softmax(b.float() / temperature, dim=-1)
    p, q = lp.exp(), lq.exp()
    kl_pq = (p * (lp - lq)).sum(-1)
    kl_qp = (q * (lq - lp)).sum(-1)
    return (0.5 * (kl_pq + kl_qp)).clamp_min(0.0).mean()


def light_independence_loss(
    t_mat: torch.Tensor,
    t_mat_other: torch.Tensor,
    cfg: LightIndependenceConfig | None = None,
    material: torch.Tensor | None = None,
    material_other: torch.Tensor | None = None,
) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
    """L_ind between material tokens under two input lights.

    t_mat, t_mat_other: (B, L, C) (any leading dims) -> (scalar loss, {"cos": C term, "kld": KL term} detached).
    material, material_other: optional (N, F) per-Gaussian material payloads of the same Gaussians under the two
    lights (``cfg.pixels``, see the module docstring): each term then adds its value on the payloads.
    With lambda_c = lambda_kld = 0 (the ``no-ind`` ablation) the loss is an exact zero that still has a graph.
    """
    cfg = cfg or LightIndependenceConfig()
    c = cosine_term(t_mat, t_mat_other)
    k = kld_term(t_mat, t_mat_other, cfg.temperature)
    if material is not None and material_other is not None:
        c = c + cosine_term(material, material_other)
        k = k + kld_term(material, material_other, cfg.temperature)
    loss = cfg.lambda_c * c + cfg.lambda_kld * k
    return loss, {"cos": c.detach(), "kld": k.detach()}


class LightIndependenceLoss(torch.nn.Module):
    """Module wrapper of :func:`light_independence_loss` (returns the scalar only)."""

    def __init__(self, cfg: LightIndependenceConfig | None = None):
        super().__init__()
        self.cfg = cfg or LightIndependenceConfig()

    def forward(self, t_mat: torch.Tensor, t_mat_other: torch.Tensor) -> torch.Tensor:
        return light_independence_loss(t_mat, t_mat_other, self.cfg)[0]


__all__ = ["LightIndependenceConfig", "LightIndependenceLoss", "cosine_term", "kld_term", "light_independence_loss"]
