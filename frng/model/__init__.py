"""F-RNG's own trainable components (paper Sec. 4 and supplement), as standalone torch modules.

Modules
-------
- :mod:`.composed`            Sec. 4 the composed model (:class:`~.composed.FRNG`): the components below put together,
                                frozen priors in, relightable neural Gaussians out
- :mod:`.composed_config`     its records: the config's ``frng`` section and a variant's architecture (``model.pt``)
- :mod:`.pixel_head`          our addition: the per-pixel inputs and the pixel head (the Lambertian start)
- :mod:`.saliency`            supplement "Saliency map computation": S_final and top-K% salient patches per view
- :mod:`.tokenizers`          Sec. 4.1 T_prior = Tokenizer(Patchify(n, a, r, m)); patchify / unpatchify
- :mod:`.fine_geometry`       Sec. 4.1 latent-interpolated fine-grained geometry (Bilinear, FineGeoDetokenizer)
- :mod:`.materialformer`      Sec. 4.2.1 MaterialFormer + MatDetokenizer (neural features or Cook-Torrance head)
- :mod:`.light_independence`  Sec. 4.2.2 L_ind = lambda_c * C + lambda_KLD * KL
- :mod:`.opacity`             our addition: a per-Gaussian residual on the backbone Gaussians' opacity logits
- :mod:`.coverage`            our addition: a screen-space gain on the rendered silhouette rim's coverage (alpha)
- :mod:`.depth`               our addition: a per-Gaussian move of the backbone's Gaussians along their input rays
- its trainer: :mod:`frng.training.frng_trainer` (L_2, L_per, L_ind, one step; stage ``frng train``)
- :mod:`frng.gaussians`       raw per-pixel parameters -> Gaussians (shared with the backbone)

Token layout contract (shared with the backbone, :mod:`frng.priors.backbone`)
-----------------------------------------------------------------------------
One object has V input views of H x W pixels; patch size p (8); patch grid h = H/p, w = W/p.

- Token grids are channels-last ``(V, h, w, D)``, with an optional batch dim in front ``(B, V, h, w, D)``:
  ``T_geo`` (D = backbone width), ``T_app`` (one grid per light; same width), ``T_prior`` (D = prior_dim).
  Token (i, j) covers pixels rows [i p, (i+1) p) x cols [j p, (j+1) p) of its view.
- Patchify order: a token's p*p per-pixel vectors are ordered ``y * p + x`` (pixel (y, x) inside the patch), with
  the C channels of a pixel contiguous -- :func:`frng.nn.patchify` / :func:`frng.nn.unpatchify`.
- IDM priors per view: ``(V, H, W, 8)`` = normal 3, albedo 3, roughness 1, metallic 1
  (:func:`.tokenizers.stack_priors`; depth is not tokenized).
- Coarse Gaussians: the backbone's GeoDetokenizer gives raw ``(V, H, W, 9)`` = [distance 1, scale 3, rotation 4,
  opacity 1] per pixel -> :func:`frng.gaussians.pixel_gaussians` -> N = V*H*W Gaussians in (view, row, col) order.
- Salient patches: ``(V, n)`` flat patch indices ``row * w + col``, n = ceil(K h w) per view (same for all views).
- Fine tokens: ``(V, M, D)``, M = n * s * s (s = upsample factor), ordered (view, selected patch, a, b);
  fine Gaussians: N = V*M*p*p in (view, fine token, y*p + x) order, on a sub-pixel grid s times denser than pixels.
- MaterialFormer sequence: ``(B, L, D)`` with L = V*h*w coarse tokens then V*M fine tokens
  (:func:`.materialformer.to_sequence` / :func:`.materialformer.split_sequence`); every token -> p*p Gaussians
  (MatDetokenizer output ``(B, L, p*p, F)``). Coarse per-Gaussian features map to the pixel order of the coarse
  Gaussians with :func:`.materialformer.coarse_features_to_pixels`; fine ones reshape to (V*M*p*p, F) directly
  (:func:`.materialformer.kept_rows`: the kept ones of both as rows of the flattened output, one gather).
- Final object = ``Gaussians.cat([coarse, fine])`` with features ``cat([coarse_feats (V*H*W, F), fine_feats])``;
  background Gaussians can be dropped with the input alpha (coarse: per pixel, as the backbone's ``keep``;
  fine: :func:`.fine_geometry.fine_keep_mask`).

Ablations: ``no-fine`` -> skip :class:`.fine_geometry.FineGeometry` (L = V*h*w); ``no-idm`` -> build every module
with ``prior_dim = 0`` (no prior parameters; passing priors raises); ``no-ind`` -> lambda_c = lambda_kld = 0;
``no-neural`` -> ``MaterialFormerConfig(head="pbr")`` + :func:`.materialformer.decode_pbr`.
"""

from frng.gaussians import GaussianDecodeConfig, Gaussians, decode, decode_raw, pixel_gaussians
from frng.model.coverage import CoverageHead
from frng.model.depth import DepthHead
from frng.model.fine_geometry import (
    FineGeoDetokenizer,
    FineGeometry,
    FineGeometryConfig,
    FineGeometryOutput,
    bilinear_tokens,
    fine_gaussian_uv,
    fine_keep_mask,
    fine_positions,
)
from frng.model.light_independence import LightIndependenceConfig, LightIndependenceLoss, light_independence_loss
from frng.model.materialformer import (
    MatDetokenizer,
    MaterialFormer,
    MaterialFormerConfig,
    MaterialHead,
    coarse_features_to_pixels,
    decode_pbr,
    split_sequence,
    to_sequence,
)
from frng.model.opacity import OpacityHead
from frng.model.saliency import SaliencyConfig, patch_scores, saliency_map, salient_patches, select_top_k
from frng.model.tokenizers import PRIOR_CHANNELS, PriorTokenizer, patchify, stack_priors, unpatchify

__all__ = [
    "CoverageHead",
    "DepthHead",
    "FineGeoDetokenizer",
    "FineGeometry",
    "FineGeometryConfig",
    "FineGeometryOutput",
    "GaussianDecodeConfig",
    "Gaussians",
    "LightIndependenceConfig",
    "LightIndependenceLoss",
    "MatDetokenizer",
    "MaterialFormer",
    "MaterialFormerConfig",
    "MaterialHead",
    "OpacityHead",
    "PRIOR_CHANNELS",
    "PriorTokenizer",
    "SaliencyConfig",
    "bilinear_tokens",
    "coarse_features_to_pixels",
    "decode",
    "decode_pbr",
    "decode_raw",
    "fine_gaussian_uv",
    "fine_keep_mask",
    "fine_positions",
    "light_independence_loss",
    "patch_scores",
    "patchify",
    "pixel_gaussians",
    "saliency_map",
    "salient_patches",
    "select_top_k",
    "split_sequence",
    "stack_priors",
    "to_sequence",
    "unpatchify",
]
