"""The composed F-RNG model (paper Sec. 4, Fig. 2): frozen priors in, relightable neural Gaussians out.

For one object with V input views (backbone cache entry, IDM priors, input images) under input light ``light``::

    S_final, top-K patches j     = Saliency(images)                                   supplement, "Saliency map"
    T_prior                      = Tokenizer(Patchify(n, a, r, m))                     Sec. 4.1, T_prior eq.
    G_coarse                     = the backbone's per-pixel Gaussians (cached GeoDetokenizer output, frozen)
    T_fine-geo/prior/app, G_fine = Bilinear(...)_j, FineGeoDetokenizer(T_fine-geo | T_fine-prior)   Sec. 4.1
    T_mat                        = MaterialFormer(T_geo (+) T_app | T_prior)  over coarse + fine tokens  Sec. 4.2.1
    G_mat                        = MatDetokenizer(T_mat)  -> per-Gaussian neural features (or Cook-Torrance params)
                                   (+ n P, the pixel's normal n in a fixed random projection P: our addition,
                                   ``frng.normal_start``, :meth:`FRNG._normal_start`)
    opacity                      = sigmoid(logit(opacity) + OpacityHead(G_mat, pixel))   our addition (.opacity)
    L_o(p)                       = 1/K sum_k Theta(f(p), w_o, w_k) L(w_k) / pdf(w_k)   Sec. 4.3 + supplement,
                                   deferred shading of the rasterized feature map (:mod:`frng.render.shading`)

Token layout and Gaussian order follow the contract in :mod:`frng.model` (coarse tokens, then fine tokens; coarse
Gaussians in (view, row, col) order, fine ones in (view, fine token, y*p + x) order). Background Gaussians are
dropped: coarse ones with the cache's ``keep`` (input alpha >= 0.5), fine ones with :func:`fine_keep_mask`.

Variants (:func:`frng.training.frng_trainer.variant_config`, from the one table :data:`frng.plan.variants.VARIANTS`): ``full``; ``no-fine`` (no FineGeometry, coarse tokens only); ``no-idm``
(``prior_dim = 0``: no tokenizer, no prior parameters anywhere; ``reconstruct`` refuses priors); ``no-ind``
(lambda_c = lambda_KLD = 0, training only); ``no-neural`` (MaterialFormer head ``pbr`` -> Cook-Torrance per
Gaussian, rendered with the GGX shader through the same deferred pipeline); ``k{P}`` (top-K = P% of the patches).

The frozen backbone is not part of this module: only its GeoDetokenizer weights are copied once into the
FineGeoDetokenizer at construction (:meth:`FRNG.from_backbone`); its outputs come from the cache, without gradients.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, replace
from pathlib import Path

import torch
from torch import nn

from frng import io
from frng.device import bf16_ok
from frng.gaussians import GaussianDecodeConfig, Gaussians
from frng.model.coverage import COVERAGE_PREFIX, CoverageHead
from frng.model.depth import DepthHead
from frng.model.fine_geometry import FineGeometry, FineGeometryConfig, fine_keep_mask, sample_pixels
from frng.model.materialformer import (
    MaterialFormerConfig,
    MaterialHead,
    decode_pbr,
    kept_rows,
    to_sequence,
)
from frng.model.opacity import GEOMETRY_CHANNELS, OpacityHead, geometry_inputs
from frng.model.saliency import SaliencyConfig, patch_scores, saliency_map, select_top_k
from frng.model.tokenizers import PriorTokenizer, stack_priors
from frng.plan.sections import architecture_bounds, key, register, section
from frng.render import RasterConfig, envmap, rasterize
from frng.render.decoder import shade_decoder
from frng.render.shading import (
    COSINE_NORMAL,
    GGX_MIN_ALBEDO,
    GGX_NORMAL,
    NeuralDecoder,
    ShadingConfig,
    ggx_shade,
    smooth_normals,
)

MODEL_KIND = "frng"
# FRNGConfig keys added after models were saved without them: the value that reproduces what those models did
SAVED_DEFAULTS = {
    "fine_in_hull": False,
    "opacity_head": False,
    "geometry_inputs": False,
    "depth_head": 0.0,
    "coverage_head": 0,
    "specular_start": False,
    "normal_start": 0.0,
}


@register("frng")
@dataclass(frozen=True)
class FRNGSection:
    """The config's ``frng`` section: the variants to train and the architecture (each key declared on its field). :func:`frng.training.frng_trainer.variant_config` turns it into a variant's :class:`FRNGConfig`."""

    CONFIG_DOC = "the F-RNG model and its variants (frng/model/composed.py)"

    variants: tuple[str, ...] = key(
        ["full", "no-fine", "no-idm", "no-ind", "no-neural", "plus"],
        "variants trained into `results/models/{variant}/`: `full` (the paper's F-RNG: every addition of "
        "`frng.plan.variants.ADDITIONS` off), its ablations in the paper's form, `no-fine` (no fine-grained "
        "Gaussians), `no-idm` (no prior tokens anywhere; its `train` job does not even depend on the IDM priors), "
        "`no-ind` (lambda_c = lambda_KLD = 0), `no-neural` (Cook-Torrance head + GGX shader), and `plus` (F-RNG+: the "
        "config's additions on, i.e. the `frng.pixel_head`, "
        "`shading.decoder_cosine`/`decoder_attenuation`/`decoder_specular`, `frng.coverage_head`, "
        "`frng.back_completion`, `frng.fine_in_hull`, `frng.normal_start` and `train.loss.ind_pixels` keys act on "
        "`plus` only), and `plus-no-{addition}` (F-RNG+ with that addition off, e.g. `plus-no-pixel-head`: the "
        "additions table; not in the default list)",
        type="array",
        items={
            "type": "string",
            "enum": [
                "full",
                "no-fine",
                "no-idm",
                "no-ind",
                "no-neural",
                "plus",
                "plus-no-pixel-head",
                "plus-no-decoder-bases",
                "plus-no-coverage-head",
                "plus-no-back-completion",
                "plus-no-fine-in-hull",
                "plus-no-normal-start",
                "plus-no-ind-pixels",
            ],
        },
    )
    k_sweep: tuple[float, ...] = key(
        [1, 2, 4, 8],
        "top-K sweep -> variants `k1`, `k2`, ...; the entry equal to `top_k_percent` IS the full model (rule "
        "`model_alias` copies `full` there, no second training)",
        type="array",
        items={"type": "number", "exclusiveMinimum": 0, "maximum": 100},
    )
    top_k_percent: float = key(
        2,
        "K: salient patches per view that get fine tokens, ceil(K h w) (paper 2%)",
        type="number",
        exclusiveMinimum=0,
        maximum=100,
    )
    upsample: int = key(
        2,
        "fine tokens per salient patch = upsample^2 (sub-pixel Gaussians s x denser)",
        type="integer",
        minimum=1,
        maximum=16,
    )
    back_completion: bool = key(
        True,
        "fewer views: every input pixel whose ray's visual-hull exit point no input view sees gets a copy of its "
        "Gaussian there (its features, its normal mirrored across the plane normal to the ray; "
        "`frng/priors/multiview.py`, `back_gaussians`), so the far side of an object seen from 2 views renders as a "
        "plausible surface instead of the background. With the 6-view rig ~4 % of the pixels get one. Cached per view "
        "count (`v{V}.back_*`, backbone cache version 3)",
        type="boolean",
    )
    fine_in_hull: bool = key(
        True,
        "the fine Gaussians a reconstruction keeps are those that project onto a foreground pixel (alpha > 0.5, the "
        "mask dilated by 1 px) of every input view (`frng.priors.multiview.inside_silhouettes`): a point outside one "
        "view's silhouette is not on the object. Without it about half of them (85 682 of 177 476 on the 21 test "
        "objects) lay off the object and rendered as a faint haze around its silhouette, which the backbone's renders "
        "do not have (docs/model-and-training.md). Models saved before the key keep every fine Gaussian",
        type="boolean",
    )
    opacity_head: bool = key(
        True,
        "a per-Gaussian residual on the opacity logit of the Gaussians F-RNG renders (the backbone's per-pixel ones, "
        "the fine ones, the far-side copies with their source's), from the pixel head's inputs and the detokenizer's "
        "output (`frng/model/opacity.py`, a 2-layer MLP of width `pixel_head` whose last layer starts at zero: an "
        "untrained head keeps the backbone's opacities); needs `pixel_head` > 0. With six views the hull's slivers "
        "and a silhouette about a pixel too wide cost LPIPS and the rim's PSNR; the head thins them "
        "(docs/model-and-training.md). Models saved before the key have none",
        type="boolean",
    )
    geometry_inputs: bool = key(
        True,
        "the opacity head also reads the backbone's own geometry at each Gaussian's input pixel: how far the backbone "
        "moved the surface off its multi-view (hull) prior and its raw opacity logit (`frng/model/opacity.py` "
        "`geometry_inputs`; the backbone cache's `raw` / `raw_prior`). Models saved before the key have none",
        type="boolean",
    )
    depth_head: float = key(
        0.15,
        "largest move (world units; the object's radius is 1) of each coarse Gaussian along its input camera's ray by "
        "a learned per-Gaussian offset, `depth_head * tanh(MLP)` from the opacity head's pixel inputs, last layer at "
        "zero (`frng/model/depth.py`); needs `pixel_head` > 0; 0 = off. The fine Gaussians and the far-side copies "
        "stay. Models saved before the key have none",
        type="number",
        minimum=0,
    )
    coverage_head: int = key(
        16,
        "hidden width of a screen-space CNN (`frng/model/coverage.py`; 0 = off) that, once per rasterized view and "
        "before shading, scales the alpha of the render's 1-px silhouette rim by a learned gain (its features "
        "unchanged; last layer at zero: an untrained head changes nothing). The ground truth's outermost pixel ring "
        "is anti-aliased, part background, where the hull's splats cover it fully. Scratch, two seeds: +0.29 dB with "
        "LPIPS unchanged (docs/model-and-training.md). It changes the silhouette, not the relighting: compare "
        "interior PSNR too. Models saved before the key have none",
        type="integer",
        minimum=0,
        maximum=4096,
    )
    specular_start: bool = key(
        True,
        "the pixel head's start (an untrained F-RNG re-renders its inputs as a Lambertian surface) also splits each "
        "pixel's colour by the IDM's metallic m and roughness r: diffuse c / E(n) (1 - m), the specular base's colour "
        "m pi c / E(n), its roughness r where m = 1 (`frng/model/composed.py` PixelHead; the neural head with IDM priors "
        "and `shading.decoder_specular` only; no-idm and no-neural start as before). Needs `idm.train.metallic_loss: "
        "bce` (with `l1` the IDM's metallic is ~0 everywhere and this changes nothing). Scratch, both on, two seeds, "
        "vs bce alone: overall +0.00 / +0.04 dB (noise), studio sensitivity 1.43 -> 1.55 / 1.56, the mirror-metal "
        "test object +1.1 / +1.8 dB under the studio, LPIPS 0.150 -> 0.130 / 0.121; sky sensitivity -0.08 / -0.10. On "
        "by default since 7abdda7's reproduction (CHANGELOG.md): overall the same, studio sensitivity +1.47 -> +1.54 "
        "(a second training seed +1.53), sky -0.11. Models saved before the key start as before",
        type="boolean",
    )
    normal_start: float = key(
        0.0,
        "an addition (departs from Sec. 4.2.1's one-layer MatDetokenizer): each Gaussian's latent feature also gets "
        "its input pixel's world normal (the IDM's; the geometry's without priors) times a fixed random 3 x C matrix "
        "of this scale (N(0, 1) from its own seed, saved with the model, not trained; `frng/model/composed.py` "
        "`FRNG._normal_start`). The paper form's features start the same on every side of an object, and its decoder "
        "learned a light-independent colour; with this start they differ with the orientation from the first step. "
        "Off by default (acts on `plus` and configs that train it); measured over the paper form in "
        "docs/studies/2026-12-05-why-the-paper-form-does-not-relight.md",
        type="number",
        minimum=0,
        maximum=10,
    )
    prior_dim: int = key(
        64,
        "IDM prior token width (PriorTokenizer, shared by FineGeoDetokenizer and MaterialFormer)",
        type="integer",
        minimum=1,
        maximum=8192,
    )
    hidden: int = key(
        256,
        "MaterialFormer width (Pre-LN, GeLU; paper 1024)",
        type="integer",
        minimum=8,
        maximum=8192,
    )
    depth: int = key(
        4,
        "MaterialFormer layers (paper 4)",
        type="integer",
        minimum=1,
        maximum=256,
    )
    heads: int = key(
        4,
        "MaterialFormer attention heads",
        type="integer",
        minimum=1,
        maximum=128,
    )
    feature_dim: int = key(
        16,
        "neural material features per Gaussian (the universal decoder's input; decoder size under `shading`)",
        type="integer",
        minimum=1,
        maximum=4096,
    )
    pixel_head: int = key(
        32,
        "hidden width of the per-Gaussian pixel head: the Gaussian's input pixel (gamma colour, alpha, and the IDM's "
        "albedo/normal/roughness/metallic unless no-idm) -> a residual on the MatDetokenizer's output; 0 = the "
        "paper's linear detokenizer alone",
        type="integer",
        minimum=0,
        maximum=4096,
    )
    saliency: SaliencyConfig = key({})


def kept_pixel_rows(m: torch.Tensor, keep_c: torch.Tensor, fine, keep_f) -> torch.Tensor:
    """A per-pixel map m (V, H, W, C) at the kept Gaussians, in their order: the coarse ones' pixels (keep_c,
    (V*H*W,)), then the fine ones sampled at their sub-pixel uv (keep_f; none without ``fine``) -> (N, C)."""
    rows = [m.reshape(-1, m.shape[-1])[keep_c]]
    if fine is not None:
        rows.append(sample_pixels(m, fine.uv).reshape(-1, m.shape[-1])[keep_f])
    return torch.cat(rows)


@dataclass
class FRNGConfig:
    """Architecture of one F-RNG variant (everything needed to rebuild it from ``model.pt``). Not a config section:
    :func:`frng.training.frng_trainer.variant_config` sets every field from the config (and the frozen backbone), so none has a default."""

    patch: int
    geo_dim: int  # the backbone's token width (T_geo and T_app)
    prior_dim: int  # 0 = no-idm
    fine: bool  # latent-interpolated fine geometry on/off (no-fine)
    top_k: float  # K as a fraction of patches per view (paper 2%)
    upsample: int  # fine tokens per selected patch = upsample^2
    hidden: int  # MaterialFormer width (paper 1024)
    depth: int  # MaterialFormer layers (paper 4)
    heads: int
    feature_dim: int  # neural material features per Gaussian
    head: str  # "neural" | "pbr" (no-neural)
    decoder_width: int  # universal decoder (paper 4 x 256)
    decoder_depth: int
    dir_freqs: int
    near: float  # the backbone's ray-distance bounds (Gaussian decoding)
    far: float
    max_radius_px: float | None  # footprint cap at render time (the backbone's, unless raster sets one)
    saliency: dict  # the frng.saliency keys (SaliencyConfig; top_k is taken from ``top_k``)
    pixel_head: int  # hidden width of the per-Gaussian pixel head (0 = off: the paper's linear detokenizer only)
    decoder_cosine: bool  # decoder output x max(0, n.w_i), n = features 0:3 (shading.decoder_cosine)
    decoder_attenuation: bool  # the decoder may also darken its Lambertian base (shading.decoder_attenuation)
    back_completion: bool  # Gaussians on the hull's unseen far side, copied from their pixels (frng.back_completion)
    decoder_specular: bool  # closed-form prefiltered specular base, features 6:10 (shading.decoder_specular)
    fine_in_hull: bool  # fine Gaussians only inside every input view's silhouette (frng.fine_in_hull)
    opacity_head: bool  # per-Gaussian opacity residual on the backbone's geometry (frng.opacity_head)
    geometry_inputs: bool  # the opacity head also reads the backbone's raw geometry (frng.geometry_inputs)
    depth_head: float  # largest move of a coarse Gaussian along its input ray (0 = off; frng.depth_head)
    coverage_head: int  # hidden width of the silhouette rim's coverage head (0 = off; frng.coverage_head)
    specular_start: bool  # the specular base starts from the IDM's metallic / roughness (frng.specular_start)
    normal_start: float  # scale of the fixed random projection of the pixel's normal added to G_mat (0 = off)

    @classmethod
    def from_dict(cls, d: dict) -> FRNGConfig:
        """Strict (:func:`frng.plan.sections.section`): a model file's ``config`` with a key this code does not know, or
        without one it needs, is an error naming it."""
        return section(cls, d)

    @classmethod
    def from_saved(cls, d: dict) -> FRNGConfig:
        """A model file's ``config``: keys added after it was saved take :data:`SAVED_DEFAULTS` (what the model was
        trained with), then :meth:`from_dict`."""
        return cls.from_dict({**SAVED_DEFAULTS, **dict(d)})

    def to_dict(self) -> dict:
        return asdict(self)

    @property
    def uses_priors(self) -> bool:
        return self.prior_dim > 0

    def saliency_config(self) -> SaliencyConfig:
        return SaliencyConfig.from_dict({**self.saliency, "top_k": self.top_k})

    def materialformer_config(self) -> MaterialFormerConfig:
        same = ("prior_dim", "hidden", "depth", "heads", "patch", "feature_dim", "head")
        return MaterialFormerConfig(geo_dim=self.geo_dim, app_dim=self.geo_dim, **{k: getattr(self, k) for k in same})


@dataclass
class Reconstruction:
    """One object's relightable asset.

    gaussians: N kept Gaussians (coarse then fine), ``features`` set to the per-Gaussian payload;
    features: (N, F) neural material features (``head='neural'``) or None;
    pbr: {"albedo" (N, 3), "roughness" (N, 1), "metallic" (N, 1), "normal" (N, 3)} (``head='pbr'``) or None;
    patch_idx: (V, n) selected salient patches (flat ``row * w + col``; n = 0 columns for no-fine);
    saliency: (V, H, W) S_final of the input views; num_coarse: how many of the N Gaussians are coarse;
    t_mat: (1, L, hidden) material tokens (kept for the light-independence loss; None at inference);
    material: (N_front, F) the per-Gaussian material the renderer reads (neural features, or the decoded GGX
    albedo, roughness, metallic, normal), of the Gaussians of input pixels (coarse then fine; far-side copies
    excluded); kept with t_mat for the light-independence loss; None at inference.
    """

    gaussians: Gaussians
    features: torch.Tensor | None
    pbr: dict | None
    patch_idx: torch.Tensor
    saliency: torch.Tensor
    num_coarse: int
    t_mat: torch.Tensor | None = None
    material: torch.Tensor | None = None


PRIOR_PIXEL_CHANNELS = ("albedo", "normal", "roughness", "metallic")
PBR_INIT_ROUGHNESS_LOGIT, PBR_INIT_METALLIC_LOGIT = 2.0, -4.0  # pbr pixel head's start: roughness ~0.9, metallic ~0.02
# Where things sit in :func:`pixel_map`'s channels (one place for the layout).
PIXEL_RATIO = slice(4, 7)  # shading-normalised colour (gamma)
# pixel_map trusts c / E(n) fully where E is at least this share of the view's bright irradiance (bright_irradiance),
# and blends to the IDM's albedo below it (shadows of hard lights, where c / E is noise clamped at its bound)
RATIO_TRUST = 0.1
PIXEL_GEO_NORMAL = 10  # geometry normal, 3 channels
PIXEL_IDM_NORMAL = 16  # the IDM's normal, 3 channels (with priors)
PIXEL_IDM_ROUGHNESS, PIXEL_IDM_METALLIC = 19, 20  # the IDM's roughness and metallic, 1 channel each (with priors)
NORMAL_START_SEED = 1234  # the fixed random projection of frng.normal_start (a buffer saved with the model)


def normal_start_projection(out_channels: int, scale: float) -> torch.Tensor:
    """``frng.normal_start``'s projection (3, out_channels): N(0, 1) x ``scale`` from a generator of its own
    (:data:`NORMAL_START_SEED`), so turning it on draws nothing from the training's random stream."""
    g = torch.Generator().manual_seed(NORMAL_START_SEED)
    return torch.randn(3, out_channels, generator=g) * float(scale)


def pixel_channels(uses_priors: bool) -> int:
    """Channels of :func:`pixel_map`: gamma colour 3, alpha 1, shading-normalised colour 3, input irradiance 3,
    geometry normal 3 (+ albedo 3, normal 3, roughness 1, metallic 1 with IDM priors)."""
    return 13 + (8 if uses_priors else 0)


def pixel_normal_index(uses_priors: bool) -> int:
    """Where the best available world normal starts in :func:`pixel_map`: the IDM's, else the geometry's."""
    return PIXEL_IDM_NORMAL if uses_priors else PIXEL_GEO_NORMAL


def bright_irradiance(E: torch.Tensor, alpha: torch.Tensor) -> torch.Tensor:
    """Per view, the 90th percentile of the irradiance E (V, H, W, 3) over the view's foreground (alpha (V, H, W, 1)
    > 0.5; the whole view where it has none): how much light the lit side receives, (V, 1, 1, 3)."""
    V = E.shape[0]
    fg = alpha[..., 0] > 0.5
    out = []
    for v in range(V):
        e = E[v][fg[v]] if fg[v].any() else E[v].reshape(-1, 3)
        out.append(torch.quantile(e.float(), 0.9, dim=0))
    return torch.stack(out)[:, None, None, :].to(E.dtype)


UNKNOWN_ALBEDO = 0.5  # the albedo the input-light estimate assumes where a model has no IDM priors (no-idm)


def input_light_sh(images: torch.Tensor, albedo: torch.Tensor | None, normals: torch.Tensor) -> torch.Tensor:
    """The input views' light as degree-2 SH radiance (9, 3), estimated from the views alone
    (:func:`frng.render.light_estimate.estimate_light_sh`: colour / albedo fitted as E(n) / pi): images (V, H, W, 4)
    linear premultiplied RGBA, albedo (V, H, W, 3) the IDM's (None: :data:`UNKNOWN_ALBEDO` everywhere), normals
    (V, H, W, 3) world. Where too few pixels are confident, a uniform light that makes the mean foreground colour
    an albedo of :data:`UNKNOWN_ALBEDO`."""
    from frng.render.light_estimate import LightEstimateError, estimate_light_sh
    from frng.render.sh import C0

    rgb, a = images[..., :3].detach().float().cpu(), images[..., 3:4].detach().float().cpu()
    alb = torch.full_like(rgb, UNKNOWN_ALBEDO) if albedo is None else albedo.detach().float().cpu()
    try:
        return estimate_light_sh(rgb, a, alb, normals.detach().float().cpu())[0]
    except LightEstimateError:
        fg = a[..., 0] > 0.5
        mean = (rgb[fg] / a[fg]).mean(0).double() if bool(fg.any()) else torch.ones(3, dtype=torch.float64)
        coeffs = torch.zeros(9, 3, dtype=torch.float64)
        coeffs[0] = mean.clamp_min(1e-3) / UNKNOWN_ALBEDO / C0  # uniform radiance r: colour = albedo x r
        return coeffs


def pixel_map(
    images: torch.Tensor, priors, V: int, normals: torch.Tensor, input_env: torch.Tensor | None = None
) -> torch.Tensor:
    """Per-pixel inputs of the pixel head.

    images (V, H, W, 4) linear premultiplied RGBA under the input light; priors IntrinsicPriors (first V views) or
    None; normals (V, H, W, 3) world normals of the backbone's geometry (:func:`frng.priors.surfels.grid_normals`);
    input_env (He, We, 3) the input light's HDR map. Returns (V, H, W, C) = [unpremultiplied gamma-2.2 colour, alpha,
    shading-normalised colour (gamma of c * pi / E(n): an albedo estimate under a Lambertian assumption, clamped
    to [0, 1]; with priors blended towards the IDM's albedo where E(n) is under :data:`RATIO_TRUST` of the view's
    :func:`bright_irradiance`: in a hard light's shadow c / E is noise, and an albedo of 4 there, the old bound,
    rendered those pixels several times too bright under any other light and drove the Lambertian base below 0
    for the whole model), input irradiance (gamma of E(n) / pi), the geometry normal, (IDM albedo, world normal, roughness,
    metallic)], where E(n) is
    the input light's irradiance at the shading normal n (the IDM's normal with priors, else the geometry's;
    degree-2 SH, :func:`frng.render.envmap.sh_irradiance`). The paper's task gives no input light: by default
    (``input_env`` None) it is ESTIMATED from these images (:func:`input_light_sh`); an ``input_env`` (He, We, 3) is
    the oracle setting "told the input light" (a labelled run, never a headline number). Dividing the light out is
    what lets the same decoder relight under another light."""
    from frng.render import envmap

    rgb, a = images[..., :3].float(), images[..., 3:4].float()
    col = (rgb / a.clamp_min(1e-3)).clamp(0, 1)
    d = priors.as_dict() if priors is not None else None
    shading_normals = d["normal"][:V] if d is not None else normals
    if input_env is None:
        coeffs = input_light_sh(images, d["albedo"][:V] if d is not None else None, shading_normals)
    else:
        coeffs = envmap.sh_project(input_env.float().cpu())
    E = envmap.sh_irradiance(coeffs.float(), shading_normals.float().cpu())
    E = E.to(images.device).clamp_min(0.0) / math.pi
    ratio = (col / E.clamp_min(1e-3)).clamp(0, 1)
    if d is not None:  # where the input light barely reaches (hard lights' shadows) c / E is noise: the IDM's albedo
        w = (E / (RATIO_TRUST * bright_irradiance(E, a)).clamp_min(1e-6)).clamp(0, 1)
        ratio = w * ratio + (1 - w) * d["albedo"][:V].to(images.device).float().clamp(0, 1)
    parts = [col ** (1 / 2.2), a, ratio ** (1 / 2.2), E ** (1 / 2.2), normals.to(images.device).float()]
    if d is not None:
        parts += [d[k][:V].to(images.device).float() for k in PRIOR_PIXEL_CHANNELS]
    return torch.cat(parts, -1)


class PixelHead(nn.Module):
    """Per-Gaussian residual on the MatDetokenizer's output from the Gaussian's own input pixel (our addition).

    The MatDetokenizer is one linear layer from a patch token to p*p Gaussians; at this project's token widths it
    cannot carry per-pixel detail (a 64 px view is only 8 x 8 tokens), so every Gaussian also sees its input pixel:
    ``g + MLP([g, pixel])`` with ``pixel`` from :func:`pixel_map` (the no-idm variant gets no prior channels). The
    last layer starts at zero (the paper's detokenizer at initialisation). With ``normal_index`` (the cosine decoder,
    ``shading.decoder_cosine``) the pixel's normal (``pixel[:, normal_index:normal_index + 3]``) is added to output
    channels 0:3, which the decoder reads as the shading normal, and the diffuse BRDF estimate c / E(n) (the
    shading-normalised colour / pi, linear) to channels 3:6, the decoder's Lambertian base: at initialisation F-RNG
    re-renders its input view under the input light and relights it as a Lambertian surface. With ``head='pbr'``
    (the no-neural ablation) the same start in Cook-Torrance terms: albedo logit(pi c / E(n)), roughness ~0.9,
    metallic ~0.02, the pixel's normal, so the ablation differs from the full model only in its appearance model.

    ``specular_start`` (``frng.specular_start``; the neural head with the IDM's priors and the decoder's specular base,
    features 6:10): the start also splits the pixel's colour by the IDM's metallic m and roughness r, as a metal
    reflects rather than diffuses: diffuse c / E(n) (1 - m) in 3:6, the specular base's colour m pi c / E(n) in 6:9
    (its ``linear`` k_s ~ f) and its roughness m logit(r) / 4 in 9 (``ggx``: roughness sigmoid(4 f_9) = r where m =
    1). A non-metal (m = 0) starts exactly as without it.

    forward(g (N, C_out), pixel (N, C_pix)) -> (N, C_out)."""

    def __init__(
        self,
        out_channels: int,
        pixel_channels: int,
        hidden: int,
        normal_index: int | None = None,
        head: str = "neural",
        specular_start: bool = False,
    ):
        super().__init__()
        if head not in ("neural", "pbr"):
            raise ValueError(f"PixelHead: head must be 'neural' or 'pbr', got {head!r}")
        if specular_start and (head != "neural" or normal_index is None or pixel_channels <= PIXEL_IDM_METALLIC):
            raise ValueError("PixelHead: specular_start needs the neural head's Lambertian start and the IDM's priors")
        self.pixel_channels, self.normal_index, self.head = pixel_channels, normal_index, head
        self.specular_start = specular_start
        self.mlp = nn.Sequential(
            nn.Linear(out_channels + pixel_channels, hidden),
            nn.GELU(),
            nn.Linear(hidden, hidden),
            nn.GELU(),
            nn.Linear(hidden, out_channels),
        )
        nn.init.zeros_(self.mlp[-1].weight)
        nn.init.zeros_(self.mlp[-1].bias)

    def forward(self, g: torch.Tensor, pixel: torch.Tensor) -> torch.Tensor:
        assert g.shape[0] == pixel.shape[0] and pixel.shape[-1] == self.pixel_channels, (g.shape, pixel.shape)
        out = g + self.mlp(torch.cat([g, pixel.to(g.dtype)], -1))
        if self.normal_index is None:
            return out
        i = self.normal_index
        normal = pixel[:, i : i + 3].to(out.dtype)
        ratio = pixel[:, PIXEL_RATIO].float() ** 2.2  # shading-normalised colour (gamma) -> pi c / E(n), an albedo
        if self.specular_start:  # neural head: a metal reflects: 3:6 diffuse, 6:9 k_s, 9 roughness
            metal = pixel[:, PIXEL_IDM_METALLIC : PIXEL_IDM_METALLIC + 1].float().clamp(0, 1)
            rough = pixel[:, PIXEL_IDM_ROUGHNESS : PIXEL_IDM_ROUGHNESS + 1].float().clamp(0.05, 0.95)
            start = torch.cat([ratio / math.pi * (1 - metal), metal * ratio, metal * torch.logit(rough) / 4.0], -1)
            return torch.cat([out[:, :3] + normal, out[:, 3:10] + start.to(out.dtype), out[:, 10:]], -1)
        if self.head == "neural":  # decoder features: 0:3 normal, 3:6 diffuse BRDF c / E(n)
            return torch.cat([out[:, :3] + normal, out[:, 3:6] + (ratio / math.pi).to(out.dtype), out[:, 6:]], -1)
        # pbr (decode_pbr's raw layout): albedo logit 0:3, roughness 3, metallic 4, normal 5:8 -> a rough
        # dielectric of albedo pi c / E(n): GGX's diffuse lobe, i.e. the same Lambertian relighting (the logit
        # kept within +-3.9, where the sigmoid still has a gradient; decode_pbr's albedo is in [GGX_MIN_ALBEDO, 1])
        albedo = torch.logit(((ratio - GGX_MIN_ALBEDO) / (1.0 - GGX_MIN_ALBEDO)).clamp(0.02, 0.98)).to(out.dtype)
        rough_metal = out.new_tensor([PBR_INIT_ROUGHNESS_LOGIT, PBR_INIT_METALLIC_LOGIT])
        return torch.cat([out[:, :3] + albedo, out[:, 3:5] + rough_metal, out[:, 5:8] + normal, out[:, 8:]], -1)


class FRNG(nn.Module):
    """F-RNG's trainable networks: PriorTokenizer, FineGeometry, MaterialHead, PixelHead, OpacityHead, universal
    decoder.

    See the module docstring for the data flow; :meth:`reconstruct` and :meth:`render` are the public API.
    """

    def __init__(self, cfg: FRNGConfig, raster: RasterConfig | None = None, shading: ShadingConfig | None = None):
        super().__init__()
        self.cfg = cfg
        self.raster_cfg = raster or RasterConfig.from_dict({})
        self.shading_cfg = shading or ShadingConfig.from_dict({})
        self.tokenizer = PriorTokenizer(cfg.prior_dim, cfg.patch) if cfg.uses_priors else None
        decode = GaussianDecodeConfig(near=cfg.near, far=cfg.far)
        self.fine = (
            FineGeometry(
                FineGeometryConfig(
                    upsample=cfg.upsample, patch=cfg.patch, geo_dim=cfg.geo_dim, prior_dim=cfg.prior_dim
                ),
                decode,
            )
            if cfg.fine
            else None
        )
        self.material = MaterialHead(cfg.materialformer_config())
        out_ch = self.material.cfg.out_channels
        lambertian_start = cfg.decoder_cosine or cfg.head == "pbr"  # the cosine decoder's base, or GGX's diffuse lobe
        # variants without the IDM's priors (no-idm) or the neural head (no-neural) start as before
        neural_specular = cfg.head == "neural" and cfg.decoder_cosine and cfg.decoder_specular
        specular_start = cfg.specular_start and cfg.uses_priors and neural_specular
        self.pixel_head = (
            PixelHead(
                out_ch,
                pixel_channels(cfg.uses_priors),
                cfg.pixel_head,
                pixel_normal_index(cfg.uses_priors) if lambertian_start else None,
                cfg.head,
                specular_start,
            )
            if cfg.pixel_head > 0
            else None
        )
        if cfg.opacity_head and self.pixel_head is None:
            raise ValueError("frng.opacity_head reads the pixel head's inputs: it needs frng.pixel_head > 0")
        n_pix = pixel_channels(cfg.uses_priors)
        n_geo = GEOMETRY_CHANNELS if cfg.geometry_inputs else 0
        self.opacity_head = OpacityHead(out_ch, n_pix + n_geo, cfg.pixel_head) if cfg.opacity_head else None
        if cfg.depth_head and self.pixel_head is None:
            raise ValueError("frng.depth_head reads the pixel head's inputs: it needs frng.pixel_head > 0")
        self.depth_head = DepthHead(out_ch, n_pix, cfg.pixel_head, cfg.depth_head) if cfg.depth_head else None
        self.coverage_head = CoverageHead(out_ch, cfg.coverage_head) if cfg.coverage_head else None
        if cfg.normal_start > 0:  # frng.normal_start: fixed (a buffer, not a parameter), saved with the model
            self.register_buffer("normal_proj", normal_start_projection(out_ch, cfg.normal_start))
        else:
            self.normal_proj = None
        if lambertian_start and self.pixel_head is not None:  # start at the Lambertian relighting of the input views
            nn.init.zeros_(self.material.detokenizer.proj.weight)
            nn.init.zeros_(self.material.detokenizer.proj.bias)
        if cfg.decoder_specular and cfg.feature_dim < 10:
            raise ValueError(
                f"the specular base (shading.decoder_specular) reads feature channels 6:10; "
                f"frng.feature_dim is {cfg.feature_dim}"
            )
        self.decoder = (
            NeuralDecoder(
                cfg.feature_dim,
                cfg.decoder_width,
                cfg.decoder_depth,
                cfg.dir_freqs,
                cosine=cfg.decoder_cosine,
                attenuation=cfg.decoder_attenuation,
            )
            if cfg.head == "neural"
            else None
        )
        if self.decoder is not None:  # start dim: softplus(-3) ~ 0.05 reflectance x cos, not ~0.7 (over-bright renders)
            # weights keep PyTorch's init: x0.1 froze the output. With the cosine decoder the MLP only adds to the
            # Lambertian base: start it near zero (softplus(-6) ~ 0.0025)
            nn.init.constant_(self.decoder.out.bias, -6.0 if cfg.decoder_cosine else -3.0)
            if cfg.decoder_attenuation:  # and take away ~2 % of it (sigmoid(-4)), where the gradient still flows
                nn.init.constant_(self.decoder.out.bias[3:], -4.0)

    # -- construction / files ------------------------------------------------------------------------------

    @classmethod
    def from_backbone(
        cls,
        cfg: FRNGConfig,
        backbone: nn.Module,
        raster: RasterConfig | None = None,
        shading: ShadingConfig | None = None,
    ) -> FRNG:
        """A fresh model whose FineGeoDetokenizer starts as the frozen backbone's GeoDetokenizer (weights copied,
        nothing shared: the backbone gets no gradient)."""
        model = cls(cfg, raster, shading)
        if model.fine is not None:
            model.fine.detokenizer.init_from(backbone.geo_detokenizer)
        return model

    def save(self, path: str | Path, extra: dict | None = None) -> None:
        """``model.pt``: {"kind": "frng", "config", "raster", "shading", "state_dict", **extra} (atomic write)."""
        state = {
            "kind": MODEL_KIND,
            "config": self.cfg.to_dict(),
            "raster": asdict(self.raster_cfg),
            "shading": asdict(self.shading_cfg),
            "state_dict": self.state_dict(),
        }
        state.update(extra or {})
        io.save_torch(state, path)

    @classmethod
    def load(cls, path: str | Path, device: torch.device | str = "cpu") -> FRNG:
        """Load ``results/models/{variant}/model.pt`` in eval mode on ``device``."""
        from frng.io import load_torch

        state = load_torch(
            path, "F-RNG model file", architecture_bounds()
        )  # weights_only: a crafted model.pt runs nothing
        if not isinstance(state, dict) or state.get("kind") != MODEL_KIND:
            kind = state.get("kind") if isinstance(state, dict) else type(state).__name__
            raise ValueError(f"{path}: not an F-RNG model file (kind {kind!r})")
        model = cls(
            FRNGConfig.from_saved(state["config"]),
            RasterConfig.from_dict(state.get("raster", {})),
            ShadingConfig.from_saved(state.get("shading", {})),
        )
        model.load_state_dict(state["state_dict"])
        model.meta = {k: v for k, v in state.items() if k not in ("state_dict",)}
        return model.to(device).eval()

    def decoder_meta(self) -> dict:
        """Decoder architecture for the asset format (:mod:`frng.apps.asset`): width, depth, input_encoding."""
        enc = "raw" if self.cfg.dir_freqs == 0 else f"raw+sincos{self.cfg.dir_freqs}"
        return {
            "width": self.cfg.decoder_width,
            "depth": self.cfg.decoder_depth,
            "input_encoding": f"[feature({self.cfg.feature_dim}), {enc}(w_o world), {enc}(w_i world)]",
            "dir_freqs": self.cfg.dir_freqs,
            "feature_dim": self.cfg.feature_dim,
            "output": self._decoder_output(),
            "cosine": self.cfg.decoder_cosine,
            "attenuation": self.cfg.decoder_attenuation,
            "head": self.cfg.head,
            "specular": self.cfg.decoder_specular,
            "coverage_hidden": self.cfg.coverage_head,  # the rim's coverage head (0: none; asset_weights)
        }

    def asset_weights(self) -> dict[str, torch.Tensor]:
        """What an asset renders with besides its Gaussians (:mod:`frng.apps.asset`): the decoder's state_dict and,
        with the coverage head, that head's under ``coverage.`` (it acts on every rasterized view, :meth:`rasterize`)."""
        out = dict(self.decoder.state_dict())
        if self.coverage_head is not None:
            out |= {f"{COVERAGE_PREFIX}{k}": v for k, v in self.coverage_head.state_dict().items()}
        return out

    def _decoder_output(self) -> str:
        if not self.cfg.decoder_cosine:
            return "softplus RGB x cos"
        base = "max(feature[3:6], 0)"
        if self.cfg.decoder_attenuation:
            base += " x (1 - sigmoid(MLP[3:6]))"
        out = f"({base} + softplus(MLP[0:3])) x max(0, n.w_i), n = normalise(feature[0:3])"
        if self.cfg.decoder_specular:
            from frng.render.prefilter import SPECULAR_FORMULAS

            ks, level = SPECULAR_FORMULAS[self.shading_cfg.specular_param]
            out += (
                f" + {ks} x prefiltered env (frng.render.prefilter, vMF kappas "
                f"400/100/25/6) at reflect(w_o, n), level {level}"
            )
        return out

    @property
    def device(self) -> torch.device:
        return next(self.parameters()).device

    # -- reconstruction -----------------------------------------------------------------------------------

    def select_patches(self, images: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """images (V, H, W, 4) -> (patch_idx (V, n), S_final (V, H, W)); n = 0 when fine geometry is off."""
        sal = saliency_map(images, None, self.cfg.saliency_config())
        if self.fine is None:
            return torch.zeros(images.shape[0], 0, dtype=torch.long, device=images.device), sal
        return select_top_k(patch_scores(sal, self.cfg.patch), self.cfg.top_k), sal

    def prior_tokens(self, priors, V: int) -> torch.Tensor | None:
        """IntrinsicPriors (>= V views; the first V are used, matching the cache's view order) -> (V, h, w, Dp)."""
        if self.tokenizer is None:
            if priors is not None:
                raise ValueError("this F-RNG variant has no prior path (no-idm) but was given IDM priors")
            return None
        if priors is None:
            raise ValueError("this F-RNG variant needs IDM priors")
        d = {k: v[:V].to(self.device).float() for k, v in priors.as_dict().items()}
        return self.tokenizer(stack_priors(d))

    def reconstruct(
        self,
        backbone_views: dict,
        light: int | list[int],
        priors=None,
        images: torch.Tensor = None,
        keep_tokens: bool = False,
        input_env: torch.Tensor | None = None,
        pixel_maps: list[torch.Tensor] | None = None,
    ) -> Reconstruction | list[Reconstruction]:
        """Build the relightable asset of one object.

        backbone_views: ``BackboneCache.views(V)`` (t_geo (V, h, w, D), raw_prior (V, H, W, 9) optional,
        means/quats/scales/opacities/keep (N = V*H*W),
        c2w (V, 4, 4), intr (V, 4), light{j}.t_app (V, h, w, D)); light: cache light index (0 = the reference light
        E_0, :func:`frng.render.envmap.reference_light`; j >= 1 extra training lights), or a
        list of indices -> one Reconstruction per light, sharing geometry (one batched MaterialFormer pass);
        priors: IntrinsicPriors of the input views (first V used) or None (required None for no-idm);
        images: (V, H, W, 4) input RGBA (linear premultiplied) under the input light, for the saliency map, the
        fine keep mask and the pixel head. keep_tokens: also return T_mat (1, L, hidden) and the per-Gaussian
        material payload for L_ind. input_env: None (the paper's task: the pixel head, ``pixel_head > 0``, estimates
        the input light from the images) or (He, We, 3) the input light's HDR map (the oracle "told the input light";
        see :func:`pixel_map`). With a list of lights, ``images`` and ``input_env`` may also be
        lists (one per light: the same views photographed under another light, for L_ind); saliency, salient
        patches and the fine keep mask always come from the first. pixel_maps: what :meth:`pixel_maps` returns for
        these inputs, when the caller kept it (training); None: computed here.
        """
        dev = self.device
        lights = [light] if isinstance(light, int) else list(light)
        B = len(lights)
        if isinstance(images, (list, tuple)):
            images_b = [x.to(dev).float() for x in images]
        else:
            images_b = [images.to(dev).float()] * B  # one tensor: its pixel map is made once below
        envs_b = list(input_env) if isinstance(input_env, (list, tuple)) else [input_env] * B
        if len(images_b) != B or len(envs_b) != B:
            raise ValueError(f"reconstruct: {B} lights but {len(images_b)} image sets and {len(envs_b)} env maps")
        bv = {k: v.to(dev) for k, v in backbone_views.items()}
        t_geo = bv["t_geo"].float()
        V, h, w, _ = t_geo.shape
        c2w, intr = bv["c2w"].float(), bv["intr"].float()
        images = images_b[0]
        patch_idx, sal = self.select_patches(images)
        t_prior = self.prior_tokens(priors, V)
        coarse = Gaussians(bv["means"].float(), bv["quats"].float(), bv["scales"].float(), bv["opacities"].float())
        keep_c = bv["keep"].bool()
        apps = torch.stack([bv[f"light{j}.t_app"].float() for j in lights])  # (B, V, h, w, D)
        if self.fine is not None:
            fine = self.fine(t_geo, patch_idx, c2w, intr, t_prior, bv.get("raw_prior"))
            keep_f = fine_keep_mask(fine.uv, images[..., 3])
            if self.cfg.fine_in_hull:  # off the object: they rendered as a haze around the silhouette
                from frng.priors.multiview import inside_silhouettes  # lazy: importing frng.priors loads every prior

                keep_f = keep_f & inside_silhouettes(fine.gaussians.means.detach(), images[..., 3], c2w, intr)
            geo_seq = to_sequence(t_geo, fine.t_geo)
            app_seq = torch.cat([to_sequence(a, self.fine.interpolate(a, patch_idx)) for a in apps])
            prior_seq = None if t_prior is None else to_sequence(t_prior, fine.t_prior)
        else:
            fine, keep_f = None, None
            geo_seq, app_seq = to_sequence(t_geo), torch.cat([to_sequence(a) for a in apps])
            prior_seq = None if t_prior is None else to_sequence(t_prior)
        geo_seq = geo_seq.expand(B, -1, -1)
        prior_seq = None if prior_seq is None else prior_seq.expand(B, -1, -1)
        t_mat, g_mat = self.material(geo_seq, app_seq, prior_seq)  # (B, L, hid), (B, L, P, C)
        rows = kept_rows(keep_c, keep_f, V, h, w, self.cfg.patch)  # the kept Gaussians' rows of g_mat[b]
        g_rows = g_mat.reshape(B, -1, g_mat.shape[-1])  # (B, L * P, C): coarse tokens' Gaussians, then fine ones
        assert g_rows.shape[1] == keep_c.numel() + (0 if keep_f is None else keep_f.numel()), (g_mat.shape, V, h, w)
        pix_b = [None] * B
        if self.pixel_head is not None:  # per-Gaussian pixel inputs, same order as the kept Gaussians below
            maps = self.pixel_maps(bv, images_b, envs_b, priors) if pixel_maps is None else pixel_maps
            for b in range(B):
                if b > 0 and maps[b] is maps[0]:
                    pix_b[b] = pix_b[0]
                    continue
                pix_b[b] = kept_pixel_rows(maps[b], keep_c, fine, keep_f)
        geo = self._geometry_inputs(bv, keep_c, fine, keep_f)
        start = None if self.normal_proj is None else self._normal_start(bv, priors, V, keep_c, fine, keep_f)
        n_coarse = int(keep_c.sum())
        # each kept coarse Gaussian's input camera centre (N = V*H*W pixels in view order), for the depth head
        origins = None if self.depth_head is None else DepthHead.origins(c2w, keep_c)
        back = self._back_completion(bv, keep_c)
        out = []
        for b in range(B):
            raw = g_rows[b].index_select(0, rows).float()  # coarse pixels, then fine Gaussians
            parts = [coarse[keep_c]]
            if fine is not None:
                parts.append(fine.gaussians[keep_f])
            # the opacity and depth heads read the detokenizer's output before the pixel head adds its Lambertian start
            dlogit = None
            if self.opacity_head is not None:
                op_in = pix_b[b] if geo is None else torch.cat([pix_b[b], geo.to(pix_b[b].dtype)], -1)
                dlogit = self.opacity_head.residual(raw, op_in)
            if self.depth_head is not None:  # coarse Gaussians along their input rays (frng/model/depth.py)
                dz = self.depth_head.offset(raw[:n_coarse], pix_b[b][:n_coarse])
                parts[0] = replace(parts[0], means=DepthHead.move(parts[0].means, origins, dz))
            if self.pixel_head is not None:
                raw = self.pixel_head(raw, pix_b[b])
            if start is not None:
                raw = raw + start
            n_front = raw.shape[0]
            if back is not None:
                raw = torch.cat([raw, self._back_features(raw, back)])
                parts.append(back["gaussians"])
            gauss = Gaussians.cat(parts)
            if dlogit is not None:  # far-side copies take their source's residual
                dlogit = dlogit if back is None else torch.cat([dlogit, dlogit[back["rows"]]])
                gauss = replace(gauss, opacities=OpacityHead.apply(gauss.opacities, dlogit))
            if self.cfg.head == "neural":
                feat, pbr = raw, None
            else:
                pbr = decode_pbr(raw)
                feat = None
                raw = torch.cat([pbr["albedo"], pbr["roughness"], pbr["metallic"], pbr["normal"]], -1)
            # L_ind's payload: what the renderer reads (decoder features, or the decoded GGX parameters: on the
            # raw logits the term pulled the Cook-Torrance ablation 1.2 dB down, a penalty of its parameterisation)
            material = raw[:n_front] if keep_tokens else None
            out.append(
                Reconstruction(
                    gauss.with_features(raw),
                    feat,
                    pbr,
                    patch_idx,
                    sal,
                    int(keep_c.sum()),
                    t_mat[b : b + 1] if keep_tokens else None,
                    material,
                )
            )
        return out[0] if isinstance(light, int) else out

    def pixel_maps(self, backbone_views: dict, images: list, input_env: list, priors=None) -> list[torch.Tensor]:
        """The pixel head's per-pixel inputs (:func:`pixel_map`, (V, H, W, C) each) of one object, one per light of
        :meth:`reconstruct` (``images`` and ``input_env`` as its lists; a light photographed with the same images
        and env map as the first gets the first's tensor itself). A fixed function of the data: training computes it
        once per object (:class:`frng.memo.TensorMemo`) and hands it to :meth:`reconstruct`."""
        from frng.priors.surfels import grid_normals  # lazy: importing frng.priors loads every prior

        dev = self.device
        bv = {k: backbone_views[k].to(dev) for k in ("means", "keep", "c2w")}
        V = bv["c2w"].shape[0]
        normals = grid_normals(bv["means"], bv["keep"].bool(), bv["c2w"].float())
        pri = priors if self.cfg.uses_priors else None
        maps = []
        for b, (im, env) in enumerate(zip(images, input_env)):
            if b > 0 and im is images[0] and env is input_env[0]:
                maps.append(maps[0])
            else:
                maps.append(pixel_map(im.to(dev).float(), pri, V, normals, env))
        return maps

    def _normal_start(self, bv: dict, priors, V: int, keep_c: torch.Tensor, fine, keep_f) -> torch.Tensor:
        """``frng.normal_start`` (our addition; the paper's MatDetokenizer, Sec. 4.2.1, is one linear layer from
        T_mat): each kept Gaussian's input pixel's world normal (the IDM's with priors, else the backbone geometry's,
        as :func:`pixel_normal_index`) through the fixed random projection ``normal_proj`` (3, C), added to the
        detokenizer's output, (N, C) in the kept Gaussians' order. At initialisation the latent features then
        already differ with the surface's orientation, which is what a decoder Theta(f | w_o, w_i) needs to shade;
        study: docs/studies/2026-12-05-why-the-paper-form-does-not-relight.md section 5."""
        if self.cfg.uses_priors:  # reconstruct's prior_tokens has refused a call without priors
            normals = priors.as_dict()["normal"][:V].to(self.device).float()
        else:
            from frng.priors.surfels import grid_normals  # lazy: importing frng.priors loads every prior

            normals = grid_normals(bv["means"], keep_c, bv["c2w"].float())
        return kept_pixel_rows(normals, keep_c, fine, keep_f) @ self.normal_proj

    def _geometry_inputs(self, bv: dict, keep_c: torch.Tensor, fine, keep_f) -> torch.Tensor | None:
        """The opacity head's extra inputs (:func:`frng.model.opacity.geometry_inputs`) of the kept Gaussians, coarse
        then fine (sampled at their sub-pixel uv), (N, GEOMETRY_CHANNELS); None without ``geometry_inputs``."""
        if self.opacity_head is None or not self.cfg.geometry_inputs:
            return None
        if "raw" not in bv or "raw_prior" not in bv:
            raise ValueError(
                "F-RNG with frng.geometry_inputs reads the backbone's raw maps: backbone_views has no 'raw' / "
                "'raw_prior' (frng.priors.cache.geometry_entry makes both)"
            )
        return kept_pixel_rows(geometry_inputs(bv["raw"].float(), bv["raw_prior"].float()), keep_c, fine, keep_f)

    def _back_completion(self, bv: dict, keep_c: torch.Tensor) -> dict | None:
        """The cache entry's far-side copies (``back_*``, :func:`frng.priors.multiview.back_gaussians`) of kept
        pixels, or None (``back_completion`` off, or a cache without them): gaussians (M), rows (M,) the source's
        row among the kept coarse Gaussians, dirs (M, 3) the source rays."""
        if not self.cfg.back_completion or "back_src" not in bv:
            return None
        src = bv["back_src"].long()
        sel = keep_c[src]
        rows = (torch.cumsum(keep_c.long(), 0) - 1)[src[sel]]
        g = Gaussians(
            bv["back_means"][sel].float(),
            bv["back_quats"][sel].float(),
            bv["back_scales"][sel].float(),
            bv["back_opacities"][sel].float(),
        )
        return {"gaussians": g, "rows": rows, "dirs": bv["back_dirs"][sel].float()}

    def _back_features(self, raw: torch.Tensor, back: dict) -> torch.Tensor:
        """Payload (M, C) of the far-side copies: their source Gaussians' rows of ``raw`` (coarse rows first), with
        the normal channels (neural features 0:3 with the cosine decoder, Cook-Torrance 5:8) mirrored across the
        plane normal to the source ray, so a copy faces away from the view it was copied from."""
        from frng.priors.multiview import mirror_normals

        rb = raw[back["rows"]]
        ns = self.normal_channels()
        if ns is None:
            return rb
        return torch.cat(
            [rb[:, : ns.start], mirror_normals(rb[:, ns], back["dirs"].to(rb.dtype)), rb[:, ns.stop :]], -1
        )

    def normal_channels(self) -> slice | None:
        """Where a Gaussian's payload holds its shading normal: Cook-Torrance 5:8, the cosine decoder's features 0:3;
        None for a decoder without a normal (``decoder_cosine`` off)."""
        if self.cfg.head == "pbr":
            return GGX_NORMAL
        return COSINE_NORMAL if self.cfg.decoder_cosine else None

    # -- rendering --------------------------------------------------------------------------------------------

    def light_samples(self, env: torch.Tensor, spp: int, generator: torch.Generator | None = None):
        """Importance samples of an (He, We, 3) env map (one set for the whole image), on the model's device."""
        seed = envmap.sample_seed(generator)
        sampler = envmap.importance_sampler(env.detach().to(self.device))
        return envmap.sample(sampler, spp, self.shading_cfg.sampling, seed)

    def rasterize(
        self, rec: Reconstruction, c2w: torch.Tensor, intr: torch.Tensor, height: int, width: int
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
        """The light-independent half of :meth:`render`: rasterize the per-Gaussian payload (neural features or
        Cook-Torrance parameters) at cameras c2w (Vt, 4, 4), intr (Vt, 4).

        Returns (maps (Vt, H, W, C) alpha-premultiplied payload, alpha (Vt, H, W, 1), c2w, intr on the model's
        device). Relighting under many lights rasterizes once and calls :meth:`shade` per light."""
        dev = self.device
        g = rec.gaussians
        rc = self.raster_cfg
        radius = rc.max_radius_px if rc.max_radius_px is not None else self.cfg.max_radius_px
        kw = {**rc.kwargs(), "max_radius_px": radius}
        c2w, intr = c2w.to(dev).float(), intr.to(dev).float()
        maps, alpha, _ = rasterize(
            g.means, g.quats, g.scales, g.opacities, g.features.float(), c2w, intr, height, width, **kw
        )
        ns = self.normal_channels()
        if ns is not None:  # screen-space normal filtering (shading.normal_blur), once for every light and consumer
            maps = smooth_normals(maps, alpha, ns, self.shading_cfg.normal_sigma_px(width))
        if self.coverage_head is not None:  # the silhouette rim's partial coverage (frng/model/coverage.py)
            maps, alpha = self.coverage_head(maps, alpha)
        return maps, alpha, c2w, intr

    def shade(
        self,
        raster: tuple,
        env: torch.Tensor,
        spp: int | None = None,
        generator: torch.Generator | None = None,
        spp_grad: int | None = None,
    ) -> torch.Tensor:
        """The per-light half of :meth:`render`: deferred shading of :meth:`rasterize`'s output under an env map
        (He, We, 3). Returns RGBA (Vt, H, W, 4), linear, premultiplied over black."""
        maps, alpha, c2w, intr = raster
        spp = spp or self.shading_cfg.spp_infer
        samples = self.light_samples(env, spp, generator)
        sc = self.shading_cfg
        # bf16 decoding at inference only (shading.bf16_infer; ~2x on AMX CPUs and GPUs, ~1e-3 relative error)
        amp = sc.bf16_infer and not torch.is_grad_enabled() and self.cfg.head == "neural" and bf16_ok(maps.device)
        with torch.autocast(maps.device.type, dtype=torch.bfloat16, enabled=amp):
            if self.cfg.head == "neural":
                rgb = shade_decoder(
                    self.decoder, maps, alpha, c2w, intr, env, samples, sc, self.cfg.decoder_specular, spp_grad
                )
            else:  # GGX (diffuse lobe in closed form with diffuse 'sh'; normals facing the camera, bounded params)
                rgb = ggx_shade(
                    maps,
                    alpha,
                    c2w,
                    intr,
                    env,
                    samples,
                    spp_grad,
                    sc.alpha_eps,
                    sc.diffuse,
                    chunk=sc.chunk_pixels,
                    chunk_pairs=sc.chunk_pairs,
                )
        return torch.cat([rgb.float(), alpha], -1)

    def set_inference_shading(self, shading: ShadingConfig) -> FRNG:
        """Take the inference-time settings (``chunk_pixels``, ``chunk_pairs``, ``bf16_infer``, ``sampling``) from
        the pipeline config's shading section instead of the ones saved with the model; architecture and training
        sample counts stay the model's. Returns self."""
        self.shading_cfg = replace(
            self.shading_cfg,
            chunk_pixels=shading.chunk_pixels,
            chunk_pairs=shading.chunk_pairs,
            bf16_infer=shading.bf16_infer,
            sampling=shading.sampling,
        )
        return self

    def render(
        self,
        rec: Reconstruction,
        env: torch.Tensor,
        c2w: torch.Tensor,
        intr: torch.Tensor,
        height: int,
        width: int,
        spp: int | None = None,
        generator: torch.Generator | None = None,
        spp_grad: int | None = None,
    ) -> torch.Tensor:
        """Render a Reconstruction under an env map (He, We, 3) at cameras c2w (Vt, 4, 4), intr (Vt, 4).

        Deferred shading: rasterize the per-Gaussian payload (:meth:`rasterize`), then per foreground pixel a
        Monte-Carlo estimate with ``spp`` importance samples of ``env`` (:meth:`shade`; default
        ``shading.spp_infer``; ``spp_grad`` of them carry gradients during training). Neural head: the universal
        decoder; pbr head: GGX. ``generator`` seeds the sample set (None: seed 0). Returns RGBA (Vt, H, W, 4),
        linear, premultiplied over black.
        """
        return self.shade(self.rasterize(rec, c2w, intr, height, width), env, spp, generator, spp_grad)


__all__ = ["FRNG", "FRNGConfig", "Reconstruction"]
