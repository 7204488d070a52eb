"""The backbone's records (:mod:`frng.priors.backbone`): the architecture keys of the config's ``backbone`` section
(:class:`BackboneArch`, each key declared on its field), the section as inference reads it (:class:`BackboneSection`;
the config holds :class:`frng.training.backbone.BackboneTrainingSection`, which adds the training) and a model's
architecture record (:class:`BackboneConfig`, saved in ``model.pt``; :data:`SAVED_DEFAULTS` for model files saved
before a key existed)."""

from __future__ import annotations

from dataclasses import asdict, dataclass, fields

from frng.plan.sections import key, section


@dataclass(frozen=True)
class BackboneArch:
    """The architecture keys of the config's ``backbone`` section (each key declared on its field), shared by the
    section (:class:`BackboneSection`) and a model's architecture record (:class:`BackboneConfig`)."""

    width: int = key(
        192,
        "transformer width (paper: 1024)",
        type="integer",
        minimum=8,
        maximum=8192,
    )
    heads: int = key(
        4,
        "transformer attention heads (paper: 16)",
        type="integer",
        minimum=1,
        maximum=128,
    )
    geo_depth: int = key(
        4,
        "GeoTransformer layers (paper: 24)",
        type="integer",
        minimum=1,
        maximum=256,
    )
    app_depth: int = key(
        2,
        "appearance-DiT layers (paper: 8)",
        type="integer",
        minimum=1,
        maximum=256,
    )
    sh_degree: int = key(
        2,
        "SH degree of the per-Gaussian colour (paper: 4)",
        type="integer",
        minimum=0,
        maximum=4,
    )
    env_height: int = key(
        32,
        "env maps are area-resized to env_height x 2 env_height, then patchified (frng/priors/envenc.py)",
        type="integer",
        minimum=8,
        maximum=2048,
    )
    env_patch: int = key(
        8,
        "patch size of the resized env maps' tokens (frng/priors/envenc.py)",
        type="integer",
        minimum=1,
        maximum=256,
    )
    near: float = key(
        1.0,
        "lower bound of each Gaussian's distance along its pixel ray (also the IDM's depth range); near < far",
        type="number",
        exclusiveMinimum=0,
    )
    far: float = key(
        4.5,
        "upper bound of each Gaussian's distance along its pixel ray (also the IDM's depth range); near < far",
        type="number",
        exclusiveMinimum=0,
    )
    denoise_steps: int = key(
        5,
        "DDIM steps per relighting pass",
        type="integer",
        minimum=1,
        maximum=1000,
    )
    den_views: int = key(
        4,
        "denoising cameras: at training, views of the target light; at inference, the first den_views input cameras",
        type="integer",
        minimum=1,
        maximum=64,
    )
    guidance: float = key(
        1.0,
        "classifier-free guidance weight (1 = conditional only; paper 3.0)",
        type="number",
        minimum=0,
    )
    cond_drop: float = key(
        0.1,
        "probability of zeroing the light tokens in training",
        type="number",
        minimum=0,
        maximum=1,
    )
    max_radius_px: float = key(
        16,
        "rasterizer footprint cap (px)",
        type="number",
        exclusiveMinimum=0,
        maximum=1024,
    )
    cues: bool = key(
        True,
        "multi-view geometry prior (`frng/priors/multiview.py`): visual-hull cues as extra tokenizer channels; the "
        "per-pixel Gaussians start at the hull distance, `footprint_px` pixels wide, opacity = input alpha; the SH "
        "head sees the input pixel's colour. false = the plain RelitLRM architecture",
        type="boolean",
    )
    hull_bins: int = key(
        48,
        "samples per pixel ray in the visual-hull sweep (inside the bounding sphere of radius 1.05)",
        type="integer",
        minimum=4,
        maximum=4096,
    )
    footprint_px: float = key(
        0.7,
        "starting size (standard deviation, pixels at the Gaussian's distance) of the per-pixel Gaussians",
        type="number",
        exclusiveMinimum=0,
    )
    pixel_features: int = key(
        16,
        "per-pixel features the AppDetokenizer hands to the per-pixel SH head",
        type="integer",
        minimum=1,
        maximum=4096,
    )
    light_cue: bool = key(
        True,
        "light cue (needs `cues`): the per-pixel SH head also sees log r, the target light's Lambertian shading ratio "
        "at each Gaussian's hull normal (degree-2 SH irradiance / pi over the map's mean radiance), and its base "
        "colour is the input colour relit by it, `c_in * exp(g + log r / 2.2)`; false = the light acts only through "
        "the DiT's light tokens (the earlier default, which measured light-blind: docs/priors.md)",
        type="boolean",
    )
    light_cue_input: str = key(
        "fit",
        "what the light cue takes for the input light: `fit` (the paper's task, where the input light is unknown: a "
        "degree-2 SH irradiance fitted to the input pixels as one constant albedo, divided out; `input_light_ratio` "
        "in frng/priors/backbone.py), `uniform` (the target light's ratio alone) or `known` (an oracle: the backbone "
        "is told the input views' map; no test-time path passes it, so such a backbone serves diagnostics only; it "
        "relit at sensitivity +1.16 dB against `fit`'s +0.68 on the 41b072a data, docs/priors.md). Models saved "
        "before `fit` became the default: their own value",
        type="string",
        enum=["uniform", "fit", "known"],
    )
    cue_in_head: bool = key(
        False,
        "the per-pixel SH head also sees the cue log r: it then learns to follow the cue only part of the way (the "
        "`fit` backbone did, against the noise of its input-light estimate); false = the base colour always carries "
        "the whole cue and the head learns what it misses. Models saved before the key: true",
        type="boolean",
    )
    surfels: bool = key(
        True,
        "at inference (`reconstruct`: caches, relighting, evaluation, `frng reconstruct`) every per-pixel Gaussian "
        "becomes its pixel's surfel, a flat Gaussian covering the pixel's footprint on the surface "
        "(frng/priors/surfels.py); training renders the learned shapes. Measured (docs/priors.md, Surfels at "
        "inference): F-RNG +0.23 dB at 6 views, +1.23 at 2, backbone +0.32 (inference only). Models saved before this "
        "key: false",
        type="boolean",
    )
    hull_fill: bool = key(
        True,
        "caches (`back_*`): flat Gaussians on the surface of the depth-carved visual hull that no input view saw and "
        "no Gaussian covers (with 2 level views: the top and the bottom), each with the colour of the nearest "
        "foreground pixel, appended to the far-side copies (frng/priors/hullfill.py). Measured "
        "(docs/model-and-training.md, Hull fill; inference only on the 9d181e4 models, 21 test objects): F-RNG +3.39 "
        "dB at 2 views, +1.09 at 4, +0.08 at 6. Models saved before this key: false",
        type="boolean",
    )
    view_select: bool = key(
        True,
        "larger by 0.1) is not rendered; caches keep it with opacity 0 (frng/priors/viewselect.py; thresholds chosen "
        "on 25 training objects). Measured (docs/priors.md, Frontal view selection; inference only): F-RNG +0.35 dB "
        "at 10 views, +0.07 at 6. Models saved before this key: false",
        type="boolean",
    )
    silhouette_cull: bool = key(
        True,
        "at inference (`reconstruct`: caches, relighting, evaluation, `frng reconstruct`) a per-pixel Gaussian that "
        "another input view sees on its background (mask dilated by 1 px; a view it lies behind or outside of says "
        "nothing) is not rendered; caches keep it with opacity 0 (frng/priors/multiview.py, `inside_silhouettes`). "
        "Measured (docs/priors.md, Silhouette cull; inference only, 21 test objects): PSNR unchanged, LPIPS -0.013 "
        "for F-RNG and the backbone alike, floaters and streaks gone from the figures. Models saved before this key: "
        "false",
        type="boolean",
    )


# Architecture keys that came after models were already saved -> the behaviour those models were trained with.
SAVED_DEFAULTS = {
    "light_cue_input": "uniform",
    "cue_in_head": True,
    "surfels": False,
    "hull_fill": False,
    "view_select": False,
    "silhouette_cull": False,
}


@dataclass(frozen=True)
class BackboneConfig(BackboneArch):
    """Architecture of a backbone model (``model.pt``'s ``config``): the section's architecture keys plus ``patch``
    (``model.patch_size``)."""

    patch: int

    @classmethod
    def from_dict(cls, d: dict) -> BackboneConfig:
        """Strict (:func:`frng.plan.sections.section`): unknown keys are errors, missing architecture keys take the
        schema's defaults; ``patch`` must be given."""
        return section(cls, d, "backbone")

    @classmethod
    def from_saved(cls, d: dict) -> BackboneConfig:
        """The architecture a saved ``model.pt`` records: keys added after it was trained take
        :data:`SAVED_DEFAULTS` (what the model did before the key existed), not today's schema defaults."""
        return cls.from_dict({**SAVED_DEFAULTS, **dict(d)})

    def to_dict(self) -> dict:
        return asdict(self)

    @property
    def sh_coeffs(self) -> int:
        return (self.sh_degree + 1) ** 2


@dataclass(frozen=True)
class BackboneSection(BackboneArch):
    """The config's ``backbone`` section as inference reads it: the architecture, the registry name and the extra lights
    of the token cache. The config holds :class:`frng.training.backbone.BackboneTrainingSection`, which adds the
    training (``backbone.train``)."""

    kind: str = key(
        "relitlrm",
        "registry name (`frng.priors.BACKBONES`); plug another backbone with `register_backbone`",
        type="string",
    )
    cache_extra_lights: int = key(
        3,
        "random TRAINING lights cached per object beside the reference light E_0 (cache light 0, "
        "`frng.render.envmap.reference_light`): L_ind's E_1 is drawn among them anew every step",
        type="integer",
        minimum=1,
        maximum=100,
    )


def backbone_config(backbone: BackboneSection, patch_size: int) -> BackboneConfig:
    """The backbone architecture of the config's ``backbone`` section with the patch size (``model.patch_size``)."""
    arch = {f.name: getattr(backbone, f.name) for f in fields(BackboneArch)}
    return BackboneConfig(**arch, patch=patch_size)
