"""F-RNG's pixel head and the per-pixel inputs it reads (our addition; :class:`frng.model.composed.FRNG` builds it):
:func:`pixel_map` (each input pixel's colour, alpha, albedo estimate c / E(n) under the estimated input light,
irradiance, normals and the IDM's priors; its channel layout in ``PIXEL_*``), :func:`kept_pixel_rows` (a per-pixel map
at the kept Gaussians), :class:`PixelHead` (a residual on the MatDetokenizer's output from the Gaussian's own input
pixel, starting at the Lambertian relighting of the input views) and ``frng.normal_start``'s fixed projection of the
pixel's normal (:func:`normal_start_projection`)."""

from __future__ import annotations

import math

import torch
from torch import nn

from frng.model.fine_geometry import sample_pixels
from frng.render.shading import GGX_MIN_ALBEDO


def kept_pixel_rows(m: torch.Tensor, keep_c: torch.Tensor, fine, keep_f) -> torch.Tensor:
    """A per-pixel map m (V, H, W, C) at the kept Gaussians, in their order: the coarse ones' pixels (keep_c,
    (V*H*W,)), then the fine ones sampled at their sub-pixel uv (keep_f; none without ``fine``) -> (N, C)."""
    rows = [m.reshape(-1, m.shape[-1])[keep_c]]
    if fine is not None:
        rows.append(sample_pixels(m, fine.uv).reshape(-1, m.shape[-1])[keep_f])
    return torch.cat(rows)


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
