"""Deferred shading under environment light: the paper's universal neural renderer and a GGX reference.

Pipeline (paper, Sec. "Universal neural renderer" + supplementary): rasterize per-Gaussian neural features to a
per-pixel feature map (:func:`frng.render.rasterize`), then for every foreground pixel p and every light sample
k of ONE sample set shared by the whole image (:func:`frng.render.envmap.sample`, importance sampled by luminance)

    L_o(p) = 1/K sum_k  rho(p, w_o, w_k) L(w_k) / pdf(w_k),

where rho is either the universal decoder Theta(feature, w_o, w_i) (:class:`NeuralDecoder`; the cosine is folded
into it: no normals, no shading frame, as in the paper) or Cook-Torrance GGX times n.w_i (:func:`ggx_reflectance`,
the test reference; :func:`ggx_shade` renders the "w/o neural appearance" ablation's maps with it, normals facing
the camera and parameters bounded). Directions are world = object frame; w_o points
from the surface to the camera, w_i towards the light (the direction the env map's radiance arrives from).

Training uses K = spp_train samples of which only the first spp_grad carry gradients (paper: 64 / 24): the value
is the full K-sample estimate, the gradient that of the spp_grad-sample estimate (an unbiased estimate of the
gradient at 24/64 of the backward cost). Inference uses spp_infer (paper 128).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import torch
from torch import nn

from frng import camera
from frng.plan.sections import key, register
from frng.render import envmap
from frng.render.envmap import EnvSamples

DIFFUSE_MODES = ("sh", "mc")
SPECULAR_PARAMS = ("linear", "softplus")  # frng.render.prefilter.specular_params (that module imports this one)
SPECULAR_MODELS = ("prefiltered", "ggx")  # frng.render.prefilter: specular_at_cameras / with_ggx_specular
# Shading keys that came after models were saved -> the behaviour those models were trained with
SAVED_DEFAULTS = {"normal_blur": 0.0, "specular_param": "softplus", "specular_model": "prefiltered"}

# Cook-Torrance parameter ranges of the no-neural ablation (:func:`frng.model.materialformer.decode_pbr` maps its
# logits into them, :func:`ggx_shade` clamps blended maps to them). Bounded so that no parameter can switch a lit
# surface off: base colour >= 0.03 (charcoal), metallic <= 0.9 (>= 10 % diffuse lobe left), roughness >= 0.08
# (alpha = 0.0064: a glossy lobe, not the near-delta the light samples miss).
GGX_MIN_ALBEDO, GGX_MIN_ROUGHNESS, GGX_MAX_METALLIC = 0.03, 0.08, 0.9
GGX_MIN_COS_VIEW = 0.1
COSINE_NORMAL, GGX_NORMAL = (
    slice(0, 3),
    slice(5, 8),
)  # where a payload holds its shading normal (smooth_normals)  # :func:`face_forward` bends shading normals to n . w_o >= ~this


@register("shading")
@dataclass(frozen=True)
class ShadingConfig:
    """The config's ``shading`` section (each key declared on its field)."""

    CONFIG_DOC = "deferred neural shading (frng/render/shading.py, ShadingConfig)"

    spp_train: int = key(
        16,
        "light samples per image in training. Paper: 64",
        type="integer",
        minimum=1,
        maximum=4096,
    )
    spp_grad: int = key(
        8,
        "of these, how many carry gradients (value = full estimate, gradient = this subset's); <= spp_train. Paper: 24",
        type="integer",
        minimum=1,
        maximum=4096,
    )
    spp_infer: int = key(
        32,
        "light samples per image at inference. Paper: 128",
        type="integer",
        minimum=1,
        maximum=4096,
    )
    decoder_width: int = key(
        64,
        "units per hidden layer of the decoder MLP. Paper: 256",
        type="integer",
        minimum=1,
        maximum=4096,
    )
    decoder_depth: int = key(
        3,
        "hidden layers of the decoder MLP. Paper: 4",
        type="integer",
        minimum=1,
        maximum=64,
    )
    dir_freqs: int = key(
        0,
        "frequency bands of the direction encoding (0: raw unit vectors)",
        type="integer",
        minimum=0,
        maximum=32,
    )
    diffuse: str = key(
        "sh",
        "how the cosine decoder's Lambertian base is integrated: `sh` in closed form from the env map's degree-2 SH "
        "irradiance (no Monte-Carlo noise; the light samples integrate only the MLP's residual; "
        "`frng.render.shading.lambert_sh`), `mc` with the light samples like the rest of the decoder (the paper's "
        "estimator). The no-neural ablation's GGX diffuse lobe likewise. Saved with the model",
        enum=["sh", "mc"],
    )
    decoder_cosine: bool = key(
        True,
        "the decoder reads a normal (features 0:3) and a diffuse BRDF value (features 3:6) and returns (diffuse + "
        "softplus(MLP)) x max(0, n.w_i); F-RNG's pixel head fills them with the best normal (IDM, else geometry) and "
        "the input colour divided by the input light's irradiance, so an untrained model already relights its input "
        "views as a Lambertian surface (frng/render/shading.py, frng/model/pixel_head.py). false = the decoder learns "
        "reflectance x cosine from scratch",
        type="boolean",
    )
    decoder_attenuation: bool = key(
        True,
        "with `decoder_cosine`: 3 more decoder outputs t scale the Lambertian base by 1 - sigmoid(t) per (w_o, w_i), "
        "so the decoder can darken it (shadowing, occlusion, fur) as well as add to it; measured on the default tier "
        "(full model, train_seed 0/1/2, same priors): median abs log2 colour scale 0.229/0.221/0.248 vs "
        "0.268/0.214/0.256 without, signed -0.12 vs -0.16 on average, fur objects 0.48-0.79 vs 0.77-1.01, PSNR +0.06 "
        "dB, SSIM/LPIPS equal (frng/render/shading.py)",
        type="boolean",
    )
    decoder_specular: bool = key(
        True,
        "with `decoder_cosine`: a closed-form specular base beside the Lambertian one, k_s L_level(r): the env map "
        "prefiltered with vMF lobes at a few sharpnesses (frng/render/prefilter.py), looked up at the reflected view "
        "direction, k_s and the level (roughness) from feature channels 6:10 (feature_dim >= 10); false = the "
        "decoder's Monte-Carlo residual alone carries highlights; ignored without `decoder_cosine`",
        type="boolean",
    )
    sampling: str = key(
        "sobol",
        "the unit-square sequence behind the light samples",
        type="string",
        enum=["random", "stratified", "sobol"],
    )
    alpha_eps: float = key(
        0.001,
        "only pixels with alpha above this are decoded",
        type="number",
        minimum=0,
    )
    chunk_pixels: int = key(
        4096,
        "pixels decoded at once (memory ~ chunk x spp x width floats); on CUDA x 64 "
        "(`frng.render.shading.CUDA_CHUNK_SCALE`)",
        type="integer",
        minimum=1,
        maximum=16777216,
    )
    chunk_pairs: int = key(
        16384,
        "at most this many (pixel, light sample) pairs decoded at once: keeps activations cache-sized (1.7x faster "
        "than 4096-pixel chunks at 128 spp on the 2-core CPU); on CUDA x 64 (`CUDA_CHUNK_SCALE`: 512 px shading 29x "
        "faster on an H200, docs/performance.md)",
        type="integer",
        minimum=1,
        maximum=67108864,
    )
    bf16_infer: bool = key(
        False,
        "relighting decodes under bf16 autocast (~2x on AMX CPUs and GPUs, ~1e-3 relative error); a CPU without bf16 "
        "units should leave it off. Inference settings (`chunk_*`, `bf16_infer`, `sampling`) come from the relighting "
        "config, not from the model file. The paper tier sets it true",
        type="boolean",
    )
    normal_blur: float = key(
        0.05,
        "screen-space normal filtering before shading (`frng.render.shading.smooth_normals`): the normal channels of "
        "the rasterized maps (cosine decoder 0:3, Cook-Torrance 5:8) take the direction of their alpha-weighted "
        "Gaussian average, standard deviation this fraction of the image width (3.2 px at 64 px). Different input "
        "views' Gaussians interleave in stripes at a new view, each with its own view's normal: without it, shading "
        "that reads the normal is striped (dark stripes in the Cook-Torrance ablation). Training and relighting both "
        "use it; 0 = off",
        type="number",
        minimum=0,
    )
    specular_param: str = key(
        "linear",
        "how feature channels 6:10 become the specular base's k_s and level "
        "(`frng.render.prefilter.specular_params`): `linear` = k_s ~ max(f - 0.035, 0) with a smooth floor (0.02 at f "
        "= 0, the diffuse channels' scale), level 3 sigmoid(4 f); `softplus` = softplus(f - 4), 3 sigmoid(f), the "
        "models saved before the key: their k_s never left its initial 0.02 (Adam moves a feature by ~lr per step, a "
        "metal's k_s of 0.5 needs f ~ 4.5). A model file or asset records its value; records without it read as "
        "`softplus` (and without `normal_blur` as 0), i.e. as they were trained",
        enum=["linear", "softplus"],
    )
    specular_model: str = key(
        "ggx",
        "the specular base of the cosine decoder (`shading.decoder_specular`): `ggx` = a Cook-Torrance (GGX) lobe "
        "with F0 = k_s (channels 6:9), roughness from channel 9 (0.5 at f = 0) and the normal turned to face the "
        "camera, estimated by Monte Carlo together with the decoder's residual "
        "(`frng.render.prefilter.with_ggx_specular`); `prefiltered` = the env map convolved with four von "
        "Mises-Fisher lobes, looked up at the mirror direction (closed form). Measured on the 4839079 reproduction's "
        "caches (docs/results.md, docs/studies/, scratch; 800 steps, training seeds 0 and 1): `ggx` +0.10 / +0.08 dB "
        "(+0.09 [0.04, 0.14] averaged, 16/21 objects), above the Cook-Torrance ablation by +0.03 [-0.10, +0.17]; "
        "training steps ~15 % longer. Records without the key read as `prefiltered`",
        enum=["prefiltered", "ggx"],
    )

    def __post_init__(self):
        if self.spp_grad > self.spp_train:
            raise ValueError(f"shading.spp_grad ({self.spp_grad}) exceeds shading.spp_train ({self.spp_train})")
        if self.diffuse not in DIFFUSE_MODES:
            raise ValueError(f"shading.diffuse must be one of {DIFFUSE_MODES}, got {self.diffuse!r}")
        if self.specular_param not in SPECULAR_PARAMS:
            raise ValueError(f"shading.specular_param must be one of {SPECULAR_PARAMS}, got {self.specular_param!r}")
        if self.specular_model not in SPECULAR_MODELS:
            raise ValueError(f"shading.specular_model must be one of {SPECULAR_MODELS}, got {self.specular_model!r}")

    @classmethod
    def from_saved(cls, d: dict) -> ShadingConfig:
        """The shading a saved model or asset records (``model.pt``'s ``shading``, ``asset.json``'s
        ``render.shading``): keys added after it was saved take :data:`SAVED_DEFAULTS` (what the model was trained
        with before the key existed), not today's schema defaults; an empty record is the schema's defaults."""
        return cls.from_dict({**SAVED_DEFAULTS, **dict(d)} if d else {})

    def normal_sigma_px(self, width: int) -> float:
        """The standard deviation in pixels of :func:`smooth_normals` in an image ``width`` pixels wide
        (``normal_blur`` is a fraction of the width, so a tier's resolution does not change what it smooths)."""
        return float(self.normal_blur) * int(width)


def encode_dirs(d: torch.Tensor, freqs: int) -> torch.Tensor:
    """Direction encoding of the decoder: the raw unit vector, plus sin/cos(2^j pi d), j < freqs (NeRF-style)."""
    if freqs <= 0:
        return d
    scales = (2.0 ** torch.arange(freqs, device=d.device, dtype=d.dtype)) * math.pi
    x = d[..., None, :] * scales[:, None]  # (..., F, 3)
    return torch.cat([d, torch.sin(x).flatten(-2), torch.cos(x).flatten(-2)], -1)


class NeuralDecoder(nn.Module):
    """Universal neural appearance decoder Theta(f, w_o, w_i) -> RGB reflectance x cosine (>= 0).

    An MLP with ``depth`` hidden layers of ``width`` units (paper: 4 x 256), ReLU, softplus output. With
    ``cosine`` (our choice at this project's data scale; ``shading.decoder_cosine``) features 0:3 carry a normal n,
    features 3:6 a diffuse BRDF value d (albedo / pi) and the output is (max(d, 0) + softplus(MLP)) max(0, n . w_i):
    a Lambertian base that the MLP refines (specular, fur, corrections) instead of learning BRDF x cosine from
    scratch. With ``attenuation`` (``shading.decoder_attenuation``) the MLP has 3 more outputs t and the output is
    (max(d, 0) (1 - sigmoid(t)) + softplus(MLP)) max(0, n . w_i): the decoder can also take light away from the
    base per (w_o, w_i) -- shadowing, occlusion, strands -- which a residual >= 0 cannot (the paper's Theta is
    unconstrained; ours is still >= 0). Input:
    [feature (C), enc(w_o), enc(w_i)] with :func:`encode_dirs` (raw directions by default). Because the light
    samples are shared by all pixels, the first layer is split: W [f; w_o; w_i] = (W_f f + W_o w_o)[p] +
    (W_i w_i)[k], computed per pixel and per sample and broadcast-added -- identical to the concatenated MLP
    at a fraction of the cost. A cosine decoder runs its MLP only on the pairs above the normal's horizon
    (:meth:`_reflectance`; the dense reference: :meth:`_reflectance_dense`).
    """

    def __init__(
        self,
        feature_dim: int,
        width: int = 256,
        depth: int = 4,
        dir_freqs: int = 0,
        cosine: bool = False,
        attenuation: bool = False,
    ):
        super().__init__()
        if depth < 1:
            raise ValueError("decoder depth must be >= 1")
        if attenuation and not cosine:
            raise ValueError(
                "decoder attenuation scales the cosine decoder's Lambertian base: it needs cosine=True "
                "(shading.decoder_cosine)"
            )
        if cosine and feature_dim < 6:
            raise ValueError(
                "a cosine decoder reads the normal and diffuse BRDF from feature channels 0:6; feature_dim must be >= 6"
            )
        self.dir_freqs, self.cosine, self.attenuation = dir_freqs, cosine, attenuation
        d_enc = 3 * (1 + 2 * dir_freqs)
        self.inp_pixel = nn.Linear(feature_dim + d_enc, width)
        self.inp_light = nn.Linear(d_enc, width, bias=False)
        self.hidden = nn.ModuleList(nn.Linear(width, width) for _ in range(depth - 1))
        self.out = nn.Linear(width, 6 if attenuation else 3)  # 0:3 residual, 3:6 attenuation logits

    def flops(self) -> tuple[int, int]:
        """(FLOPs per decoded (pixel, sample) pair, FLOPs per pixel) of the MLP's matrix products (multiply + add
        = 2): the hidden and output layers plus the first layer's add run per pair, the first layer's pixel half
        per pixel (its sample half, per sample, is negligible). What a roofline of the shading counts."""
        w = self.inp_pixel.out_features
        per_pair = w + sum(2 * layer.in_features * layer.out_features for layer in [*self.hidden, self.out])
        return per_pair, 2 * self.inp_pixel.in_features * w

    def forward(self, features: torch.Tensor, wo: torch.Tensor, wi: torch.Tensor) -> torch.Tensor:
        """features (P, C), wo (P, 3), wi (K, 3) -> (P, K, 3): the full reflectance x cosine."""
        return self._reflectance(features, wo, wi, with_diffuse=True)

    def residual(self, features: torch.Tensor, wo: torch.Tensor, wi: torch.Tensor) -> torch.Tensor:
        """The cosine decoder without its Lambertian base: softplus(MLP) max(0, n . w_i), minus the attenuated share
        max(d, 0) sigmoid(t) max(0, n . w_i) with ``attenuation`` (then it can be negative), (P, K, 3). Shading with
        ``shading.diffuse: sh`` integrates this by Monte Carlo and adds the base in closed form
        (:func:`lambert_sh`)."""
        if not self.cosine:
            raise ValueError("NeuralDecoder.residual needs a cosine decoder (shading.decoder_cosine)")
        return self._reflectance(features, wo, wi, with_diffuse=False)

    def _mlp(self, h: torch.Tensor) -> torch.Tensor:
        """The hidden and output layers on first-layer pre-activations h (..., W) -> raw outputs (..., 3 | 6)."""
        h = torch.relu(h)
        for layer in self.hidden:
            h = torch.relu(layer(h))
        return self.out(h)

    def _first(self, features, wo, wi) -> tuple[torch.Tensor, torch.Tensor]:
        """The split first layer: (W_f f + W_o w_o + bias) per pixel (P, W), W_i w_i per sample (K, W)."""
        a = self.inp_pixel(torch.cat([features, encode_dirs(wo, self.dir_freqs)], -1))
        return a, self.inp_light(encode_dirs(wi, self.dir_freqs))

    def _reflectance(self, features, wo, wi, with_diffuse: bool) -> torch.Tensor:
        """features (P, C), wo (P, 3), wi (K, 3) -> (P, K, 3). A cosine decoder's output is exactly 0 where
        n . w_i <= 0 (below the horizon of the pixel's normal: about half of the pairs under a shared sample set),
        so its MLP runs only on the lit (pixel, sample) pairs, gathered and scattered back (same values as
        :meth:`_reflectance_dense`, the reference, up to float summation order; half the decoder's FLOPs)."""
        assert features.dim() == 2 and wo.shape == (features.shape[0], 3) and wi.dim() == 2, (features.shape, wi.shape)
        if not self.cosine:
            return self._reflectance_dense(features, wo, wi, with_diffuse)
        a, b = self._first(features, wo, wi)
        n = nn.functional.normalize(features[:, :3].float(), dim=-1, eps=1e-6)
        cos = n @ wi.float().T  # (P, K)
        pi, ki = torch.nonzero(cos > 0, as_tuple=True)  # the lit pairs, row-major
        raw = self._mlp(a.index_select(0, pi) + b.index_select(0, ki))  # (N, 3 | 6)
        out = nn.functional.softplus(raw[:, :3]).float()
        d = features[:, 3:6].float().clamp_min(0.0).index_select(0, pi)  # (N, 3)
        if self.attenuation:
            out = out - d * torch.sigmoid(raw[:, 3:6].float())
        if with_diffuse:
            out = out + d
        out = out * cos[pi, ki][:, None]
        return out.new_zeros(features.shape[0], wi.shape[0], 3).index_put((pi, ki), out)

    def _reflectance_dense(self, features, wo, wi, with_diffuse: bool) -> torch.Tensor:
        """:meth:`_reflectance` on every (pixel, sample) pair: the pure broadcast reference, (P, K, 3)."""
        a, b = self._first(features, wo, wi)
        raw = self._mlp(a[:, None, :] + b[None, :, :])
        out = nn.functional.softplus(raw[..., :3])
        if self.cosine:  # the rendering equation's cosine, factored out: the MLP only learns the BRDF beyond diffuse
            n = nn.functional.normalize(features[:, :3].float(), dim=-1, eps=1e-6)
            out = out.float()
            d = features[:, 3:6].float().clamp_min(0.0)[:, None, :]  # (P, 1, 3)
            if self.attenuation:  # the share of the base that does not arrive: d (1 - sigmoid(t)) + softplus(r)
                out = out - d * torch.sigmoid(raw[..., 3:6].float())
            if with_diffuse:
                out = out + d
            out = out * (n @ wi.float().T).clamp_min(0.0)[..., None]
        return out


def lit_pairs(maps: torch.Tensor, alpha: torch.Tensor, wi: torch.Tensor, alpha_eps: float = 1e-3) -> tuple[int, int]:
    """(foreground pixels, lit (pixel, sample) pairs) of a cosine decoder's G-buffer: maps (V, H, W, C) premultiplied
    features with the normal in channels 0:3, alpha (V, H, W, 1), sample directions wi (K, 3); a pair is lit where
    n . w_i > 0 (:meth:`NeuralDecoder._reflectance` decodes only those). For rooflines and benchmarks."""
    assert maps.shape[:3] == alpha.shape[:3] and wi.dim() == 2 and wi.shape[-1] == 3, (maps.shape, wi.shape)
    fg = alpha[..., 0] > alpha_eps
    n = maps[fg][:, :3].float()
    return int(fg.sum()), int(((n @ wi.to(n).T) > 0).sum())


def lambert_sh(
    maps: torch.Tensor, alpha: torch.Tensor, sh_coeffs: torch.Tensor, alpha_eps: float = 1e-3
) -> torch.Tensor:
    """The cosine decoder's Lambertian base in closed form: d E(n) per pixel, premultiplied by alpha.

    maps (V, H, W, C) alpha-premultiplied decoder features (channels 0:3 a normal n, 3:6 a diffuse BRDF d, as
    :class:`NeuralDecoder` reads them), alpha (V, H, W, 1), sh_coeffs (9, 3) degree-2 SH of the env map
    (:func:`frng.render.envmap.sh_project`). E(n) = int L max(0, n . w) dw from the SH (:func:`frng.render.envmap.sh_irradiance`;
    exact for the map's l <= 2 part, which carries ~all of a cosine lobe's integral). The same integral the Monte
    Carlo estimate of ``d max(0, n . w_i)`` converges to, without its noise: at 16-32 importance samples of an HDR
    map that noise is a visible per-image error. Pixels with alpha <= alpha_eps are 0. Returns (V, H, W, 3).
    """
    assert maps.shape[:3] == alpha.shape[:3] and maps.shape[-1] >= 6, (maps.shape, alpha.shape)
    f = maps.float() / alpha.float().clamp_min(alpha_eps)
    return sh_diffuse(f[..., 3:6], f[..., :3], alpha, sh_coeffs, alpha_eps)


def sh_diffuse(
    brdf: torch.Tensor, normal: torch.Tensor, alpha: torch.Tensor, sh_coeffs: torch.Tensor, alpha_eps: float = 1e-3
) -> torch.Tensor:
    """Closed-form radiance of a w_i-independent BRDF: brdf (V, H, W, 3) (un-premultiplied, clamped >= 0) x
    E(normal) (normal (V, H, W, 3), normalised here) from degree-2 SH coefficients (9, 3), premultiplied by alpha
    (V, H, W, 1); 0 where alpha <= alpha_eps. Returns (V, H, W, 3)."""
    assert sh_coeffs.shape == (9, 3), sh_coeffs.shape
    n = nn.functional.normalize(normal.float(), dim=-1, eps=1e-6)
    E = envmap.sh_irradiance(sh_coeffs.to(n.device, n.dtype), n).clamp_min(0.0)
    return torch.where(alpha > alpha_eps, brdf.float().clamp_min(0.0) * E * alpha.float(), torch.zeros_like(E))


def ggx_reflectance(albedo, roughness, metallic, normal, wo, wi, diffuse: bool = True) -> torch.Tensor:
    """Cook-Torrance BRDF x cosine, (P, K, 3): Lambert + GGX (Trowbridge-Reitz) D, separable Smith G, Schlick F.

    albedo (P, 3), roughness (P, 1) (perceptual; alpha = roughness^2, clamped >= 1e-3), metallic (P, 1),
    normal (P, 3) unit, wo (P, 3), wi (K, 3). F0 = lerp(0.04, albedo, metallic); diffuse = (1 - F(n.w_o))
    (1 - metallic) albedo / pi (weighting by F(n.w_o) rather than F(w_o.h) keeps a white dielectric's
    furnace albedo <= 1 at grazing angles). Zero below either horizon. ``diffuse=False``: the specular lobe only
    (the diffuse lobe in closed form: :func:`ggx_diffuse_brdf`).
    """
    n = normal[:, None, :]
    v = wo[:, None, :]
    l = wi[None, :, :]
    nl = (n * l).sum(-1, keepdim=True)
    nv = (n * v).sum(-1, keepdim=True)
    h = v + l
    h = h / h.norm(dim=-1, keepdim=True).clamp(min=1e-12)
    nh = (n * h).sum(-1, keepdim=True).clamp(min=0.0)
    vh = (v * h).sum(-1, keepdim=True).clamp(min=0.0)
    a2 = (roughness.clamp(min=0.0316) ** 4)[:, None, :]  # alpha^2, alpha = roughness^2 >= 1e-3
    D = a2 / (math.pi * (nh * nh * (a2 - 1.0) + 1.0) ** 2)
    nl_c, nv_c = nl.clamp(min=1e-6), nv.clamp(min=1e-6)

    def g1(c):
        return 2.0 * c / (c + torch.sqrt(a2 + (1.0 - a2) * c * c))

    G = g1(nl_c) * g1(nv_c)
    m = metallic[:, None, :]
    F0 = 0.04 * (1.0 - m) + albedo[:, None, :] * m
    F = F0 + (1.0 - F0) * (1.0 - vh) ** 5
    spec = D * G * F / (4.0 * nl_c * nv_c)
    visible = ((nl > 0) & (nv > 0)).to(spec.dtype)
    if not diffuse:
        return spec * nl_c * visible
    diff = ggx_diffuse_brdf(albedo, metallic, normal, wo)[:, None, :]
    return (diff + spec) * nl_c * visible


def ggx_diffuse_brdf(albedo, metallic, normal, wo) -> torch.Tensor:
    """The diffuse lobe of :func:`ggx_reflectance` (without the cosine), (P, 3): (1 - F(n.w_o)) (1 - metallic)
    albedo / pi, zero where n.w_o <= 0; it does not depend on w_i, so its integral against the light is a
    Lambertian one."""
    nv = (normal * wo).sum(-1, keepdim=True)
    F0 = 0.04 * (1.0 - metallic) + albedo * metallic
    F_v = F0 + (1.0 - F0) * (1.0 - nv.clamp(0.0, 1.0)) ** 5  # diffuse gets what the view-side Fresnel lets in
    return (1.0 - F_v) * (1.0 - metallic) * albedo / math.pi * (nv > 0).to(albedo.dtype)


# The chunk sizes of ``shading`` are the CPU's (a 16k-pair chunk keeps the 4 x 256 decoder's activations in cache); on
# CUDA both are multiplied by this. A 16k-pair chunk is ~6 GFLOP of decoder, ~0.1 ms on a GPU, so the per-chunk
# launches and syncs set the time: at 512 px on an H200 the shading ran at 2 % of the card's bf16 matmul rate
# (docs/performance.md "On a GPU"). 64x: 1M pairs, ~0.5 GB of bf16 activations per decoder layer.
CUDA_CHUNK_SCALE = 64


def _estimate(reflectance, per_pixel, wo, samples: EnvSamples, chunk: int, chunk_pairs: int | None) -> torch.Tensor:
    w = (samples.radiance / samples.pdf[:, None]).to(wo.dtype)  # (K, 3)
    wi = samples.dirs.to(wo.dtype)
    if wo.is_cuda:
        chunk, chunk_pairs = chunk * CUDA_CHUNK_SCALE, chunk_pairs and chunk_pairs * CUDA_CHUNK_SCALE
    if chunk_pairs:  # (pixel, sample) pairs per chunk: keeps the decoder's activations cache-sized for any spp
        chunk = max(1, min(chunk, chunk_pairs // max(1, wi.shape[0])))
    outs = []
    for s in range(0, wo.shape[0], chunk):
        rho = reflectance(*(t[s : s + chunk] for t in per_pixel), wo[s : s + chunk], wi)  # (p, K, 3)
        outs.append((rho.to(w.dtype) * w).mean(1))
    return torch.cat(outs) if outs else wo.new_zeros(0, 3)


def shade_pixels(
    reflectance: Callable,
    per_pixel: Sequence[torch.Tensor],
    wo: torch.Tensor,
    samples: EnvSamples,
    spp_grad: int | None = None,
    chunk: int = 4096,
    chunk_pairs: int | None = None,
) -> torch.Tensor:
    """Monte-Carlo outgoing radiance (P, 3) of P pixels under one shared light-sample set.

    reflectance(*per_pixel_chunk, wo_chunk, wi) -> (p, K, 3) (:class:`NeuralDecoder` with per_pixel =
    (features,), or :func:`ggx_reflectance` with (albedo, roughness, metallic, normal)); wo (P, 3) unit;
    samples: K directions, pdfs and radiances. With ``spp_grad`` < K (and grad enabled) only the first spp_grad
    samples carry gradients: value = the K-sample estimate, gradient = that of the spp_grad-sample estimate.
    Pixels are processed ``chunk`` at a time (memory ~ chunk x K x decoder width), and at most ``chunk_pairs``
    (pixel, sample) pairs at a time when given (``shading.chunk_pairs``: 16k pairs ran the 4 x 256 decoder 1.7x
    faster than 4096-pixel chunks at 128 spp on a 2-core CPU: the activations stay in cache).
    """
    K = samples.dirs.shape[0]
    if spp_grad is None or spp_grad >= K or not torch.is_grad_enabled():
        return _estimate(reflectance, per_pixel, wo, samples, chunk, chunk_pairs)
    g = EnvSamples(*(t[:spp_grad] for t in samples))
    rest = EnvSamples(*(t[spp_grad:] for t in samples))
    est_g = _estimate(reflectance, per_pixel, wo, g, chunk, chunk_pairs)
    with torch.no_grad():
        est_rest = _estimate(reflectance, per_pixel, wo, rest, chunk, chunk_pairs)
    value = (spp_grad * est_g.detach() + (K - spp_grad) * est_rest) / K
    return value + (est_g - est_g.detach())


def deferred_shade(
    reflectance: Callable,
    maps: Sequence[torch.Tensor],
    alpha: torch.Tensor,
    c2w: torch.Tensor,
    intrinsics: torch.Tensor,
    samples: EnvSamples | Sequence[EnvSamples],
    spp_grad: int | None = None,
    alpha_eps: float = 1e-3,
    normalize: bool = True,
    background: torch.Tensor | None = None,
    chunk: int = 4096,
    chunk_pairs: int | None = None,
) -> torch.Tensor:
    """Shade rasterized per-pixel maps under an environment light.

    maps: per-pixel inputs of ``reflectance``, each (V, H, W, D) as returned by :func:`frng.render.rasterize`
    (alpha-premultiplied; e.g. ``[features]`` for the neural decoder, or ``[albedo, roughness, metallic,
    normal]`` for GGX); alpha (V, H, W, 1); cameras c2w (V, 4, 4), intrinsics (V, 4); samples: one
    :class:`~frng.render.envmap.EnvSamples` shared by all views, or one per view. Only pixels with alpha > alpha_eps
    are decoded. With ``normalize`` the maps are divided by alpha before decoding and the radiance is
    multiplied by alpha (un-premultiply, shade, premultiply); ``background`` (3,) is composited behind.
    Returns RGB (V, H, W, 3).
    """
    V, H, W = alpha.shape[:3]
    _, d = camera.pixel_rays(c2w.to(alpha.dtype), intrinsics.to(alpha.dtype), H, W)
    a = alpha[..., 0]
    out = alpha.new_zeros(V, H, W, 3)
    per_view = not isinstance(samples, EnvSamples)
    for v in range(V):
        ys, xs = torch.nonzero(a[v] > alpha_eps, as_tuple=True)
        if ys.numel() == 0:
            continue
        av = a[v, ys, xs][:, None]
        inputs = [m[v, ys, xs] / av if normalize else m[v, ys, xs] for m in maps]
        rgb = shade_pixels(
            reflectance, inputs, -d[v, ys, xs], samples[v] if per_view else samples, spp_grad, chunk, chunk_pairs
        )
        if normalize:
            rgb = rgb * av
        vv = torch.full_like(ys, v)
        out = out.index_put((vv, ys, xs), rgb)
    if background is not None:
        out = out + (1.0 - alpha) * background.to(out.dtype)
    return out


def gaussian_blur(x: torch.Tensor, sigma_px: float) -> torch.Tensor:
    """Separable Gaussian blur of images x (V, H, W, C), standard deviation ``sigma_px`` pixels, truncated at 3 sigma,
    zero outside the image (premultiplied maps: outside is empty). Differentiable. Returns (V, H, W, C)."""
    assert x.dim() == 4, x.shape
    r = max(1, int(math.ceil(3.0 * sigma_px)))
    t = torch.arange(-r, r + 1, device=x.device, dtype=torch.float32)
    k = torch.exp(-0.5 * (t / sigma_px) ** 2)
    k = (k / k.sum()).to(x.dtype)
    C = x.shape[-1]
    y = x.permute(0, 3, 1, 2)
    y = nn.functional.conv2d(y, k.view(1, 1, 1, -1).expand(C, 1, 1, -1), padding=(0, r), groups=C)
    y = nn.functional.conv2d(y, k.view(1, 1, -1, 1).expand(C, 1, -1, 1), padding=(r, 0), groups=C)
    return y.permute(0, 2, 3, 1)


def smooth_normals(maps: torch.Tensor, alpha: torch.Tensor, normals: slice, sigma_px: float) -> torch.Tensor:
    """Screen-space normal filtering of a deferred G-buffer: the normal channels ``normals`` of maps (V, H, W, C)
    (alpha-premultiplied, alpha (V, H, W, 1)) get the direction of their alpha-weighted Gaussian average over
    ``sigma_px`` pixels (:func:`gaussian_blur` of the premultiplied normals over that of alpha), keeping each pixel's
    own length and premultiplication; every other channel is returned as it is. ``sigma_px <= 0``: maps unchanged.

    Why: the backbone's per-pixel Gaussians of different input views land at slightly different depths, so at a new
    view the front-most layer alternates between views in stripes whose normals (each view's own estimate) disagree
    by tens of degrees; the blended normal map is striped, and so is any shading that reads it (measured on the
    default tier: dark stripes in the Cook-Torrance ablation where the ground truth is lit, and in the full model's
    Lambertian base). The rendered depth is striped too, so its normals are no better. Returns (V, H, W, C)."""
    assert maps.shape[:3] == alpha.shape[:3] and alpha.shape[-1] == 1, (maps.shape, alpha.shape)
    if sigma_px <= 0:
        return maps
    n = maps[..., normals].float()
    a = alpha.float()
    avg = gaussian_blur(n, sigma_px) / gaussian_blur(a, sigma_px).clamp_min(1e-6)
    length = (n / a.clamp_min(1e-6)).norm(dim=-1, keepdim=True)
    smoothed = nn.functional.normalize(avg, dim=-1, eps=1e-8) * length * a
    return torch.cat([maps[..., : normals.start], smoothed.to(maps.dtype), maps[..., normals.stop :]], -1)


def face_forward(normal: torch.Tensor, wo: torch.Tensor, min_cos: float = GGX_MIN_COS_VIEW) -> torch.Tensor:
    """Shading normals (P, 3) of two-sided surfels seen along wo (P, 3) (unit, surface -> camera): normalised,
    flipped where they face away from the camera (a splat is seen from either side; a blended or mirrored normal
    can point away from a new view), then bent towards w_o where n . w_o < min_cos (n + (min_cos - n . w_o) w_o,
    renormalised: a grazing normal's Fresnel term would leave no diffuse light). One-sided Cook-Torrance is zero
    wherever n . w_o <= 0: lit pixels at silhouettes and on back-facing normals rendered black (the no-neural
    ablation's holes). Differentiable, finite for any input (a zero normal becomes w_o)."""
    n = nn.functional.normalize(normal, dim=-1, eps=1e-8)
    nv = (n * wo).sum(-1, keepdim=True)
    n = torch.where(nv < 0, -n, n)
    n = n + (min_cos - nv.abs()).clamp_min(0.0) * wo
    return nn.functional.normalize(n, dim=-1, eps=1e-8)


def _ggx_pixels(albedo, roughness, metallic, normal, wo, wi, diffuse: bool = True):
    """:func:`ggx_reflectance` on blended (un-premultiplied) maps: parameters clamped to the decode ranges, the
    normal through :func:`face_forward`."""
    return ggx_reflectance(
        albedo.clamp(GGX_MIN_ALBEDO, 1),
        roughness.clamp(GGX_MIN_ROUGHNESS, 1),
        metallic.clamp(0, GGX_MAX_METALLIC),
        face_forward(normal, wo),
        wo,
        wi,
        diffuse,
    )


def _ggx_pixels_specular(albedo, roughness, metallic, normal, wo, wi):
    return _ggx_pixels(albedo, roughness, metallic, normal, wo, wi, diffuse=False)


def ggx_shade(
    maps: torch.Tensor,
    alpha: torch.Tensor,
    c2w: torch.Tensor,
    intrinsics: torch.Tensor,
    env: torch.Tensor,
    samples: EnvSamples | Sequence[EnvSamples],
    spp_grad: int | None = None,
    alpha_eps: float = 1e-3,
    diffuse: str = "sh",
    chunk: int = 4096,
    chunk_pairs: int | None = None,
) -> torch.Tensor:
    """Cook-Torrance shading of rasterized pbr maps (the no-neural ablation): maps (V, H, W, 8) alpha-premultiplied
    (albedo 0:3, roughness 3, metallic 4, normal 5:8), alpha (V, H, W, 1), cameras c2w (V, 4, 4), intrinsics (V, 4),
    env (He, We, 3), samples as :func:`deferred_shade`. Blended parameters are clamped to the decode ranges
    (``GGX_*``) and normals oriented by :func:`face_forward`. ``diffuse='sh'``: the diffuse lobe in closed form
    (:func:`ggx_diffuse_brdf` x the SH irradiance at the oriented normal), Monte Carlo for the specular lobe;
    ``'mc'``: both by Monte Carlo. Returns RGB (V, H, W, 3), premultiplied, 0 where alpha <= alpha_eps."""
    split = [maps[..., 0:3], maps[..., 3:4], maps[..., 4:5], maps[..., 5:8]]
    rgb = deferred_shade(
        _ggx_pixels if diffuse != "sh" else _ggx_pixels_specular,
        split,
        alpha,
        c2w,
        intrinsics,
        samples,
        spp_grad,
        alpha_eps,
        chunk=chunk,
        chunk_pairs=chunk_pairs,
    )
    if diffuse != "sh":
        return rgb
    rgb = rgb.float()
    V, H, W = alpha.shape[:3]
    f = maps.float() / alpha.float().clamp_min(alpha_eps)
    _, d = camera.pixel_rays(c2w.float(), intrinsics.float(), H, W)
    wo = -d.reshape(-1, 3)
    n = face_forward(f[..., 5:8].reshape(-1, 3), wo)
    brdf = ggx_diffuse_brdf(
        f[..., 0:3].clamp(GGX_MIN_ALBEDO, 1).reshape(-1, 3),
        f[..., 4:5].clamp(0, GGX_MAX_METALLIC).reshape(-1, 1),
        n,
        wo,
    ).reshape(V, H, W, 3)
    sh = envmap.sh_project(env.detach().float().cpu()).float()
    return rgb + sh_diffuse(brdf, n.reshape(V, H, W, 3), alpha, sh, alpha_eps)
