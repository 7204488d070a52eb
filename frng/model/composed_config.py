"""The composed model's records (:mod:`frng.model.composed`): the config's ``frng`` section (:class:`FRNGSection`:
the variants to train and the architecture, each key declared on its field) and the architecture of one variant
(:class:`FRNGConfig`, saved in ``model.pt``; :data:`SAVED_DEFAULTS` for model files saved before a key existed)."""

from __future__ import annotations

from dataclasses import asdict, dataclass

from frng.model.materialformer import MaterialFormerConfig
from frng.model.saliency import SaliencyConfig
from frng.plan.sections import key, register, section

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
        "m pi c / E(n), its roughness r where m = 1 (`frng/model/pixel_head.py` PixelHead; the neural head with IDM priors "
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
