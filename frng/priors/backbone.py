"""A RelitLRM-style backbone at configurable size (paper "Preliminaries", Eqs. 1-4; notes/relitlrm.md).

RelitLRM's code and weights are not public, so the pipeline trains this small re-implementation of the same
architecture and then freezes it; F-RNG only ever reads its tokens.

Geometry (deterministic, computed once per object)::

    T_geo = GeoTransformer(Patchify(I_i (+) Pluecker_i))          tokens (B, V, h, w, D)
    G_geo = GeoDetokenizer(T_geo)                                 one Gaussian per input pixel

Appearance (a diffusion transformer, x0 prediction through rendering)::

    T_all = [T_noised (+) T_light (+) T_geo (+) T_step]
    T_app = DiT(T_all)[geometry positions]                        tokens (B, V, h, w, D)
    G_app = AppDetokenizer(T_app)                                 SH coefficients per Gaussian

x0-hat is the rendering of (G_geo, G_app) at the denoising cameras; DDIM turns it into the next sample.
Relighting with the backbone = one full denoising pass per new light (the paper's "RelitLRM" baseline).

Image conventions: views are premultiplied linear RGB (composited on black), mapped to [-1, 1] with
:func:`frng.priors.diffusion.to_diffusion_space` before tokenization.

Multi-view geometry prior (``cues``, on by default; paper tier too). A transformer that has seen a few hundred
objects cannot learn multi-view stereo from scratch (RelitLRM saw ~1M), so the geometry stage is given what
comparing the views along the known camera rays says (:mod:`frng.priors.multiview`): per input pixel the soft
visual hull's distance, its normal and a photo-agreement score. They enter twice:

- as extra tokenizer channels: every view's patch sees [diffusion-space RGB, Pluecker rays, alpha, cues], so T_geo
  (and through it T_app and F-RNG's tokens) carries the object's shape;
- as a per-pixel bias of the raw 9-vector (:meth:`RelitLRMBackbone.prior_raw`): distance = the hull distance,
  isotropic scale = ``footprint_px`` pixels at that distance, identity rotation, opacity = the input alpha. The
  GeoDetokenizer starts at zero, so an untrained backbone already renders the hull with the inputs' colours
  (measured: within 0.1 dB of ground-truth depth in novel-view PSNR); training learns residuals (concavities).

Appearance gets the pixel's own input colour the same way: the AppDetokenizer emits ``pixel_features`` per pixel,
and a per-pixel MLP over [those, the input pixel's gamma colour, alpha] gives the SH coefficients plus a per-channel
log-gain g, with ``SH_DC += (c_in * exp(g) - 0.5) / C0``: at initialisation (zero last layer) each Gaussian has its
input pixel's colour, and relighting learns how that colour changes with the light (:meth:`sh_coefficients`,
``pixels`` = :meth:`pixel_inputs`). ``cues: false`` restores the plain RelitLRM tokenizer/detokenizers.

Rendering (x0-hat). Geometry: :func:`frng.gaussians.pixel_gaussians` decodes the GeoDetokenizer's raw 9-vectors
along the input pixel rays (RelitLRM's constants, ``near``/``far`` from the config). Gaussians of input pixels
outside the object mask (input alpha < 0.5) are not rendered (``keep`` mask: the inputs are RGBA and the mask is
known at inference too; this halves the rasterization cost and removes background floaters). Colour: the SH
coefficients of a Gaussian are evaluated per rendering camera in the direction from the camera centre to the
Gaussian's mean (:func:`frng.render.sh.eval_sh`, real SH as in 3DGS), ``colour = max(SH(dir) + 0.5, 0)`` in the
DIFFUSION (gamma 1/2.2) space, rasterized over black: ``x0_hat = 2 * render - 1``; linear RGB = render^2.2.

Denoising cameras (RelitLRM leaves them open):
- training: up to ``den_views`` cameras at which the target light's clean images exist (the target views of a
  target light, or the input views when the target light is one of the object's input lights, which includes
  re-rendering the input light itself); the loss is on all of that light's available views (denoising +
  supervision views);
- inference: the caller's cameras; by default (:meth:`RelitLRMBackbone.relight`) the first ``den_views`` input
  cameras, which every object has (an input view's pose is on the same sphere as the target views, so it is
  in the training distribution). The final Gaussians can then be rendered at any camera.

Classifier-free guidance: light tokens are zeroed with probability ``cond_drop`` in training; at inference the
guided SH is ``sh_u + guidance * (sh_c - sh_u)`` (the render is linear in SH up to the clamp, so this is the
same as mixing x0-hats); guidance 1.0 runs only the conditional pass.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import torch
from torch import nn

from frng import camera
from frng.gaussians import GaussianDecodeConfig, Gaussians, isotropic_raw, pixel_gaussians
from frng.nn import PatchDetokenizer, PatchTokenizer, Transformer, timestep_embedding
from frng.priors.backbone_config import BackboneConfig
from frng.priors.diffusion import NoiseSchedule, from_diffusion_space, to_diffusion_space
from frng.priors.envenc import EnvTokenizer
from frng.priors.multiview import CUE_CHANNELS, geometry_cues, inside_silhouettes
from frng.priors.surfels import grid_normals, pixel_surfels
from frng.priors.viewselect import frontal_keep
from frng.render import rasterize
from frng.render.sh import C0, eval_sh

GEO_CHANNELS = 9  # distance 1, scale 3, rotation 4, opacity 1 (RelitLRM's split)


def ray_distance_target(obj_gbuffer_depth: torch.Tensor, c2w: torch.Tensor, intr: torch.Tensor) -> torch.Tensor:
    """Camera-z depth (V, H, W, 1) -> distance along each pixel's unit ray (V, H, W, 1)."""
    from frng import camera

    V, H, W, _ = obj_gbuffer_depth.shape
    _, d = camera.pixel_rays(c2w, intr, H, W)
    cos = (d * c2w[:, None, None, :3, 2]).sum(-1, keepdim=True)  # ray direction . camera forward
    return obj_gbuffer_depth / cos.clamp_min(1e-6)


class BackboneGeometry(NamedTuple):
    """What :meth:`RelitLRMBackbone.reconstruct` returns for one object (V views, N = V*H*W Gaussians).

    t_geo (1, V, h, w, D); raw (V, H, W, 9) the decoded Gaussians' raw parameters; gaussians (N) (with ``surfels``:
    their pixels' surfels, :func:`frng.priors.surfels.pixel_surfels`, not raw's shapes); keep (N,) bool: the
    Gaussians rendered = input alpha >= 0.5 (with ``view_select``: less those another input view covers more
    squarely, :func:`frng.priors.viewselect.frontal_keep`); raw_prior (V, H, W, 9) the multi-view prior's part of raw
    (zeros with ``cues: false``); pixels (1, V, H, W, 4) the per-pixel appearance inputs
    :meth:`RelitLRMBackbone.denoise` takes."""

    t_geo: torch.Tensor
    raw: torch.Tensor
    gaussians: Gaussians
    keep: torch.Tensor
    raw_prior: torch.Tensor
    pixels: torch.Tensor


class RelitLRMBackbone(nn.Module):
    """Geometry transformer + appearance DiT. See the module docstring for the equations."""

    def __init__(self, cfg: BackboneConfig):
        super().__init__()
        self.cfg = cfg
        D, p = cfg.width, cfg.patch
        self.input_tokenizer = PatchTokenizer(3 + 6 + (1 + CUE_CHANNELS if cfg.cues else 0), D, p)
        self.geo_transformer = Transformer(D, cfg.geo_depth, cfg.heads)
        self.geo_detokenizer = PatchDetokenizer(D, GEO_CHANNELS, p)
        if cfg.cues:  # start at the multi-view prior (see the module docstring)
            nn.init.zeros_(self.geo_detokenizer.proj.weight)
            nn.init.zeros_(self.geo_detokenizer.proj.bias)
        self.noisy_tokenizer = PatchTokenizer(3 + 6, D, p)
        self.env_tokenizer = EnvTokenizer(D, cfg.env_height, cfg.env_patch)
        self.step_mlp = nn.Sequential(nn.Linear(D, D), nn.SiLU(), nn.Linear(D, D))
        self.type_embed = nn.Parameter(torch.zeros(4, D))  # geo, light, noisy, step
        nn.init.normal_(self.type_embed, std=0.02)
        self.dit = Transformer(D, cfg.app_depth, cfg.heads)
        if cfg.cues:
            F_ = cfg.pixel_features
            self.app_detokenizer = PatchDetokenizer(D, F_, p)
            self.pixel_head = nn.Sequential(
                nn.Linear(F_ + 4 + (3 if cfg.light_cue and cfg.cue_in_head else 0), 2 * F_),
                nn.GELU(),
                nn.Linear(2 * F_, 3 * cfg.sh_coeffs + 3),
            )
            nn.init.zeros_(self.pixel_head[-1].weight)
            nn.init.zeros_(self.pixel_head[-1].bias)
        else:
            self.app_detokenizer = PatchDetokenizer(D, 3 * cfg.sh_coeffs, p)
            self.pixel_head = None
        self.schedule = NoiseSchedule()

    # -- geometry ----------------------------------------------------------------------------------

    def _view_input(self, rgb: torch.Tensor, c2w: torch.Tensor, intr: torch.Tensor) -> torch.Tensor:
        """(B, V, H, W, 3) linear RGB + cameras -> (B, V, H, W, 9) = diffusion-space RGB (+) Pluecker rays."""
        B, V, H, W, _ = rgb.shape
        with torch.autocast(device_type=rgb.device.type, enabled=False):  # ray geometry in fp32
            o, d = camera.pixel_rays(c2w.reshape(B * V, 4, 4).float(), intr.reshape(B * V, 4).float(), H, W)
            rays = camera.plucker(o, d).reshape(B, V, H, W, 6)
        return torch.cat([rgb if rgb.dtype != torch.bool else rgb.float(), rays], dim=-1)

    @torch.no_grad()
    def prior_raw(self, images: torch.Tensor, alpha: torch.Tensor, c2w: torch.Tensor, intr: torch.Tensor):
        """Multi-view cues and the raw 9-vector they imply (see the module docstring), per object of the batch.

        images (B, V, H, W, 3), alpha (B, V, H, W, 1), c2w (B, V, 4, 4), intr (B, V, 4).
        Returns cue features (B, V, H, W, CUE_CHANNELS), raw (B, V, H, W, 9) such that decoding raw alone
        (:func:`frng.gaussians.decode_raw`) gives: distance = hull distance, isotropic scale = ``footprint_px`` pixels
        at that distance, identity rotation, opacity = alpha (clamped to [0.02, 0.98]); and the hull normals in the
        world frame (B, V, H, W, 3) (zero where a ray misses the hull)."""
        c = self.cfg
        feats, raws, normals = [], [], []
        with torch.autocast(device_type=images.device.type, enabled=False):  # geometry in fp32, as at inference
            for b in range(images.shape[0]):
                cb, ib, ab = c2w[b].float(), intr[b].float(), alpha[b].float()
                cues = geometry_cues(images[b].float(), ab, cb, ib, c.near, c.far, bins=c.hull_bins)
                feats.append(cues["features"])
                raws.append(isotropic_raw(cues["distance"], ab, ib[:, 0], c.footprint_px, self.decode_config()))
                hit = cues["hit"][..., 0] > 0
                rot = cb[:, None, None, :3, :3].expand(*hit.shape, 3, 3)  # camera -> world
                n = torch.zeros_like(cues["normal"])  # zero where the ray misses the hull
                n[hit] = (rot[hit] @ cues["normal"][hit][..., None])[..., 0]
                normals.append(n)
        return torch.stack(feats), torch.stack(raws), torch.stack(normals)

    def encode_geometry(
        self,
        images: torch.Tensor,
        alpha: torch.Tensor,
        c2w: torch.Tensor,
        intr: torch.Tensor,
        cues: tuple[torch.Tensor, torch.Tensor, torch.Tensor] | None = None,
    ):
        """Input views -> geometry tokens and raw per-pixel Gaussian parameters.

        images: (B, V, H, W, 3) linear premultiplied RGB; alpha (B, V, H, W, 1); c2w: (B, V, 4, 4); intr: (B, V, 4).
        cues: what :meth:`prior_raw` returns for these inputs, when the caller kept it from an earlier call (the
        backbone's training reuses the rig views' cues, :class:`frng.training.backbone.CueCache`); None:
        computed here. Returns T_geo (B, V, h, w, D), raw (B, V, H, W, 9), the multi-view prior's part of raw
        (B, V, H, W, 9; zeros with ``cues: false``), so that ``raw - prior`` is what the GeoDetokenizer added, and
        the world-frame hull normals (B, V, H, W, 3; zeros with ``cues: false``) the light cue reads.
        """
        assert images.shape[:-1] == alpha.shape[:-1] and images.shape[-1] == 3, (images.shape, alpha.shape)
        x = self._view_input(to_diffusion_space(images), c2w, intr)
        normals = None
        if self.cfg.cues:
            cue_feats, prior, normals = self.prior_raw(images, alpha, c2w, intr) if cues is None else cues
            assert prior.shape == (*images.shape[:-1], 9), (prior.shape, images.shape)
            x = torch.cat([x, 2.0 * alpha.to(x.dtype) - 1.0, cue_feats.to(x.dtype)], dim=-1)
        tok = self.input_tokenizer(x)  # (B, V, h, w, D)
        B, V, h, w, D = tok.shape
        t_geo = self.geo_transformer(tok.reshape(B, V * h * w, D)).reshape(B, V, h, w, D)
        raw = self.geo_detokenizer(t_geo)
        if not self.cfg.cues:
            prior = torch.zeros_like(raw, dtype=torch.float32)
            normals = torch.zeros(*raw.shape[:-1], 3, device=raw.device)
        return t_geo, raw.float() + prior, prior, normals

    # -- appearance ----------------------------------------------------------------------------------

    def appearance_tokens(
        self,
        t_geo: torch.Tensor,
        env: torch.Tensor | None,
        noisy: torch.Tensor,
        den_c2w: torch.Tensor,
        den_intr: torch.Tensor,
        t: torch.Tensor,
    ) -> torch.Tensor:
        """One DiT pass. t_geo (B, V, h, w, D); env (B, He, We, 3) HDR or None (unconditional: light tokens
        zeroed, as in classifier-free guidance training); noisy (B, Vd, H, W, 3) diffusion-space samples at the
        denoising cameras den_c2w (B, Vd, 4, 4), den_intr (B, Vd, 4); t (B,) integer timesteps.
        Returns T_app (B, V, h, w, D)."""
        B, V, h, w, D = t_geo.shape
        geo = t_geo.reshape(B, V * h * w, D) + self.type_embed[0]
        if env is None:
            light = torch.zeros(B, self.env_tokenizer.num_tokens, D, device=t_geo.device, dtype=t_geo.dtype)
        else:
            light = self.env_tokenizer(env)
        light = light + self.type_embed[1]
        noisy_tok = self.noisy_tokenizer(self._view_input(noisy, den_c2w, den_intr)).flatten(1, 3) + self.type_embed[2]
        step = self.step_mlp(timestep_embedding(t, D)).unsqueeze(1) + self.type_embed[3]
        out = self.dit(torch.cat([geo, light, noisy_tok, step], dim=1))
        return out[:, : V * h * w].reshape(B, V, h, w, D)

    def pixel_inputs(
        self,
        images: torch.Tensor,
        alpha: torch.Tensor,
        normals: torch.Tensor | None,
        input_env: torch.Tensor | None = None,
    ) -> torch.Tensor:
        """Per-pixel appearance inputs of one object: images (V, H, W, 3) linear premultiplied, alpha (V, H, W, 1),
        world-frame hull normals (V, H, W, 3) -> (1, V, H, W, C) = [unpremultiplied gamma-2.2 colour in [0, 1],
        alpha] (C = 4), then with ``light_cue`` the normals the cue reads (C = 7), then with ``light_cue_input:
        known`` the input light's log shading ratio at them (C = 10; :meth:`light_ratio` of ``input_env``
        (He, We, 3), the input views' HDR map, which that mode requires)."""
        col = (images.float() / alpha.float().clamp_min(1e-3)).clamp(0, 1) ** (1 / 2.2)
        parts = [col, alpha.float()]
        if self.cfg.light_cue:
            assert normals is not None and normals.shape == images.shape, None if normals is None else normals.shape
            parts.append(normals.float())
            if self.cfg.light_cue_input == "known":
                if input_env is None:
                    raise ValueError(
                        "this backbone (light_cue_input: known) needs the input views' env map: "
                        "reconstruct(..., input_env=) / pixel_inputs(..., input_env=)"
                    )
                assert input_env.dim() == 3 and input_env.shape[-1] == 3, input_env.shape
                parts.append(self.light_ratio(input_env[None].to(normals.device), normals[None].float())[0])
        return torch.cat(parts, -1)[None]

    @staticmethod
    def light_ratio(env: torch.Tensor | None, normals: torch.Tensor) -> torch.Tensor:
        """The light cue: log of the target light's Lambertian shading ratio at each Gaussian's hull normal.

        env (B, He, We, 3) HDR or None (unconditional: zeros); normals (B, V, H, W, 3) world frame (zero = no
        normal: ratio 1). Returns log r (B, V, H, W, 3), r = (E(n) / pi) / mean radiance of the map, per channel,
        E from the map's degree-2 SH (:func:`frng.render.envmap.sh_irradiance`): r = 1 under a uniform map, and a white
        Lambertian surface lit by the map has radiance r x its mean radiance. Clamped to [e^-4, e^2]."""
        if env is None:
            return torch.zeros_like(normals)
        from frng.render.envmap import sh_irradiance, sh_project

        out = []
        for b in range(env.shape[0]):
            coeffs = sh_project(env[b].float().clamp_min(0.0)).to(normals.device)  # (9, 3) float64
            mean = (coeffs[0] / (4.0 * math.pi * C0)).clamp_min(1e-6)
            n = normals[b].double()
            has_n = n.norm(dim=-1) > 0.5
            e = mean.expand(*n.shape[:-1], 3).clone()  # no normal: ratio 1
            e[has_n] = sh_irradiance(coeffs, n[has_n]) / math.pi
            out.append((e.clamp_min(1e-8) / mean).log().clamp(-4.0, 2.0).float())
        return torch.stack(out)

    @staticmethod
    def input_light_ratio(pixels: torch.Tensor) -> torch.Tensor:
        """The input light's log shading ratio, estimated from the input pixels alone (``light_cue_input: fit``: the
        backbone is not told the input light, as RelitLRM is not): per object, a degree-2 SH irradiance fitted by
        least squares to the linear colours of the foreground pixels that have a hull normal, as if the object had
        one constant albedo (its scale cancels in the ratio). pixels (B, V, H, W, 7) from :meth:`pixel_inputs` ->
        log r_in (B, V, H, W, 3) in :meth:`light_ratio`'s units (ratio 1 where there is no normal, or too few
        pixels to fit)."""
        from frng.render.envmap import SH_IRRADIANCE_BANDS
        from frng.render.sh import sh_basis

        assert pixels.shape[-1] == 7, pixels.shape
        px = pixels.detach().double().cpu()
        col, a, n = px[..., :3] ** 2.2, px[..., 3], px[..., 4:7]
        has_n = n.norm(dim=-1) > 0.5
        band = px.new_tensor([SH_IRRADIANCE_BANDS[0]] + [SH_IRRADIANCE_BANDS[1]] * 3 + [SH_IRRADIANCE_BANDS[2]] * 5)
        A = sh_basis(2, n) * band / math.pi  # (B, V, H, W, 9): a white Lambertian surface's radiance per SH coeff
        out = torch.zeros(*px.shape[:-1], 3, dtype=torch.float64)
        for b in range(px.shape[0]):
            fg = has_n[b] & (a[b] > 0.5)
            if int(fg.sum()) < 27:
                continue
            sol = torch.linalg.lstsq(A[b][fg], col[b][fg]).solution  # (9, 3): albedo x the light's SH coeffs
            mean = (sol[0] / (4.0 * math.pi * C0)).clamp_min(1e-6)  # the fitted light's mean radiance x albedo
            e = A[b] @ sol
            e = torch.where(has_n[b][..., None], e, mean.expand_as(e))
            out[b] = (e.clamp_min(1e-3 * mean) / mean).log().clamp(-4.0, 2.0)
        return out.to(device=pixels.device, dtype=torch.float32)

    def sh_coefficients(
        self, t_app: torch.Tensor, pixels: torch.Tensor | None = None, env: torch.Tensor | None = None
    ) -> torch.Tensor:
        """T_app (B, V, h, w, D) -> SH coefficients per Gaussian (B, V*H*W, K, 3), K = (degree + 1)^2.

        pixels (B, V, H, W, C) from :meth:`pixel_inputs`: required with ``cues`` (the per-pixel colour path);
        with ``light_cue`` it carries the normals and env (B, He, We, 3) (None: unconditional) gives the light cue
        (:meth:`light_ratio`): the base colour is the input colour relit by it, ``c_in * exp(g + log r / 2.2)``
        (gamma space), so an untrained head already relights as a Lambertian surface: under an input light it
        assumes uniform (``light_cue_input: uniform``), relative to the input light estimated from the pixels
        (``fit``: log r = log r_target - :meth:`input_light_ratio`) or to the input light it is told (``known``:
        minus the ratio ``pixels`` carries). With ``cue_in_head`` the head also sees log r and can learn to follow
        it only part of the way (it does, where the cue is noisy: README "Priors")."""
        B = t_app.shape[0]
        K = self.cfg.sh_coeffs
        if self.pixel_head is None:
            return self.app_detokenizer(t_app).reshape(B, -1, K, 3)
        if pixels is None:
            raise ValueError("this backbone (cues: true) needs the input pixels: sh_coefficients(t_app, pixels)")
        feat = self.app_detokenizer(t_app)  # (B, V, H, W, F)
        known = self.cfg.light_cue and self.cfg.light_cue_input == "known"
        n_in = 10 if known else 7 if self.cfg.light_cue else 4
        assert pixels.shape[:-1] == feat.shape[:-1] and pixels.shape[-1] == n_in, (pixels.shape, feat.shape)
        head_in = [feat, pixels[..., :4].to(feat.dtype)]
        log_r = None
        if self.cfg.light_cue:
            log_r = self.light_ratio(env, pixels[..., 4:7])
            if env is not None and self.cfg.light_cue_input == "fit":  # relight relative to the estimated input light
                log_r = log_r - self.input_light_ratio(pixels)
            elif env is not None and known:  # relative to the input light the caller gave (pixel_inputs)
                log_r = log_r - pixels[..., 7:10].float()
            if self.cfg.cue_in_head:
                head_in.append(log_r.to(feat.dtype))
        out = self.pixel_head(torch.cat(head_in, -1)).float()
        sh = out[..., : 3 * K].reshape(B, -1, K, 3)
        gain = out[..., 3 * K :].reshape(B, -1, 3)
        if log_r is not None:
            gain = gain + log_r.reshape(B, -1, 3) / 2.2
        base = (pixels[..., :3].float().reshape(B, -1, 3) * gain.exp() - 0.5) / C0
        return torch.cat([sh[:, :, :1] + base[:, :, None], sh[:, :, 1:]], dim=2)

    # -- Gaussians and rendering -----------------------------------------------------------------------

    def decode_config(self) -> GaussianDecodeConfig:
        return GaussianDecodeConfig(near=self.cfg.near, far=self.cfg.far)

    def gaussians(self, raw: torch.Tensor, c2w: torch.Tensor, intr: torch.Tensor) -> Gaussians:
        """One object's raw params (V, H, W, 9) on its input cameras (V, 4, 4), (V, 4) -> N = V*H*W Gaussians."""
        return pixel_gaussians(raw, c2w, intr, self.decode_config())

    def render(
        self,
        gauss: Gaussians,
        sh: torch.Tensor,
        c2w: torch.Tensor,
        intr: torch.Tensor,
        height: int,
        width: int,
        keep: torch.Tensor | None = None,
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Render Gaussians with SH colour at cameras c2w (Vr, 4, 4), intr (Vr, 4).

        sh: (N, K, 3); keep: (N,) bool (None = all). Returns diffusion-space-gamma RGB in [0, inf) (Vr, H, W, 3)
        premultiplied over black, alpha (Vr, H, W, 1) and alpha-weighted depth (Vr, H, W, 1).
        ``x0_hat = 2 * rgb - 1``; linear RGB = rgb.clamp(0, 1) ** 2.2."""
        if keep is not None:
            gauss, sh = gauss[keep], sh[keep]
        centres = c2w[:, :3, 3].float()
        dirs = gauss.means[None] - centres[:, None]  # (Vr, N, 3)
        dirs = dirs / dirs.norm(dim=-1, keepdim=True).clamp_min(1e-8)
        colours = (eval_sh(self.cfg.sh_degree, sh.float()[None], dirs) + 0.5).clamp_min(0.0)  # (Vr, N, 3)
        return rasterize(
            gauss.means,
            gauss.quats,
            gauss.scales,
            gauss.opacities,
            colours,
            c2w.float(),
            intr.float(),
            height,
            width,
            max_radius_px=self.cfg.max_radius_px,
        )

    @torch.no_grad()
    def back_gaussians(self, gauss: Gaussians, alpha: torch.Tensor, c2w: torch.Tensor, intr: torch.Tensor) -> dict:
        """Far-side copies of one object's per-pixel Gaussians where no input view sees the hull's far side
        (:func:`frng.priors.multiview.back_gaussians`), then, with ``hull_fill``, the fills of the hull's surface that
        neither they nor the pixels' Gaussians cover (:func:`frng.priors.hullfill.hull_fill_gaussians`; same keys,
        appended). gauss: the N = V*H*W per-pixel Gaussians; alpha (V, H, W, 1), c2w (V, 4, 4), intr (V, 4)."""
        from frng.priors.hullfill import hull_fill_gaussians
        from frng.priors.multiview import back_gaussians

        alpha, c2w, intr = alpha.float(), c2w.float(), intr.float()
        args = (gauss.means, gauss.quats, gauss.scales, gauss.opacities, alpha, c2w, intr)
        back = back_gaussians(*args, self.cfg.far, self.cfg.hull_bins)
        if not self.cfg.hull_fill:
            return back
        keep = alpha.reshape(-1) >= 0.5
        fill = hull_fill_gaussians(gauss.means, gauss.scales, gauss.opacities, keep, alpha, c2w, intr, extra=back)
        return {k: torch.cat([back[k], fill[k].to(back[k].dtype)]) for k in back}

    # -- denoising (DDIM with x0 prediction, classifier-free guidance) -------------------------------------

    def guided_sh(self, t_geo, env, x_t, den_c2w, den_intr, t: torch.Tensor, guidance: float, pixels=None):
        """SH (B, N, K, 3) and conditional T_app (B, V, h, w, D) of one DiT step with guidance (see module doc)."""
        t_app = self.appearance_tokens(t_geo, env, x_t, den_c2w, den_intr, t)
        sh = self.sh_coefficients(t_app, pixels, env)
        if guidance != 1.0 and env is not None:
            sh_u = self.sh_coefficients(self.appearance_tokens(t_geo, None, x_t, den_c2w, den_intr, t), pixels, None)
            sh = sh_u + guidance * (sh - sh_u)
        return sh, t_app

    @torch.no_grad()
    def denoise(
        self,
        t_geo: torch.Tensor,
        gauss: Gaussians,
        keep: torch.Tensor | None,
        env: torch.Tensor | None,
        den_c2w: torch.Tensor,
        den_intr: torch.Tensor,
        height: int,
        width: int,
        steps: int | None = None,
        guidance: float | None = None,
        generator: torch.Generator | None = None,
        pixels: torch.Tensor | None = None,
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """One full DDIM pass for one object under one light (the backbone's relighting).

        t_geo (1, V, h, w, D); gauss: the object's N Gaussians; env (1, He, We, 3) or None; den_c2w (Vd, 4, 4),
        den_intr (Vd, 4); pixels (1, V, H, W, 4) from :meth:`pixel_inputs` (required with ``cues``).
        Returns the final SH (N, K, 3) and the final step's conditional T_app (1, V, h, w, D).
        """
        steps = steps or self.cfg.denoise_steps
        guidance = self.cfg.guidance if guidance is None else guidance
        Vd = den_c2w.shape[0]
        x = torch.randn(1, Vd, height, width, 3, generator=generator, device=t_geo.device)
        ts = self.schedule.ddim_timesteps(steps)
        sh = t_app = None
        for i, t in enumerate(ts):
            tt = torch.full((1,), t, device=t_geo.device, dtype=torch.long)
            sh, t_app = self.guided_sh(t_geo, env, x, den_c2w[None], den_intr[None], tt, guidance, pixels)
            if i + 1 < len(ts):
                rgb, _, _ = self.render(gauss, sh[0], den_c2w, den_intr, height, width, keep)
                x0 = (2.0 * rgb - 1.0).clamp(-1.0, 1.0)[None]
                x = self.schedule.ddim_step(x, x0, t, ts[i + 1])
        return sh[0].float(), t_app

    def inference_geometry(
        self, gauss: Gaussians, keep: torch.Tensor, c2w: torch.Tensor, intr: torch.Tensor
    ) -> tuple[Gaussians, torch.Tensor]:
        """What :meth:`reconstruct` renders of the per-pixel Gaussians (N = V*H*W; keep (N,) bool: the foreground
        pixels'; c2w (V, 4, 4), intr (V, 4)): with ``surfels`` their pixels' surfels (:mod:`frng.priors.surfels`),
        with ``view_select`` keep less the layers another view sees more squarely (:mod:`frng.priors.viewselect`),
        with ``silhouette_cull`` less the Gaussians another input view sees on its background (outside the visual
        hull: a foreground pixel's depth that fell off the surface, e.g. at a silhouette where the pixel mixes the
        object's and the background's distances, renders as a floater or an epipolar streak in every other view).
        The first two read the normals of the Gaussians' depth maps, taken without gradient (training with
        ``backbone.train.inference_geometry`` moves the means, not the surfels' planes). Returns (gaussians, keep)."""
        c = self.cfg
        if not (c.surfels or c.view_select or c.silhouette_cull):
            return gauss, keep
        with torch.no_grad():  # surfels keep the means: the selection reads the same points either way
            depth_n = grid_normals(gauss.means, keep, c2w) if c.surfels or c.view_select else None
            rendered = frontal_keep(gauss.means, keep, c2w, intr, depth_n) if c.view_select else keep
            if c.silhouette_cull:
                V = c2w.shape[0]
                H = W = int(round((keep.shape[0] // V) ** 0.5))
                masks = keep.reshape(V, H, W).float()  # keep = the input alpha >= 0.5
                rendered = rendered & inside_silhouettes(gauss.means, masks, c2w, intr, unseen_inside=True)
        if c.surfels:
            gauss = pixel_surfels(gauss, keep, c2w, intr, depth_n)
        return gauss, rendered

    @torch.no_grad()
    def reconstruct(
        self,
        images: torch.Tensor,
        alpha: torch.Tensor,
        c2w: torch.Tensor,
        intr: torch.Tensor,
        input_env: torch.Tensor | None = None,
    ) -> BackboneGeometry:
        """Geometry of one object from V input views: images (V, H, W, 3) linear premultiplied, alpha
        (V, H, W, 1), c2w (V, 4, 4), intr (V, 4); input_env (He, We, 3): the input views' HDR map, required by
        ``light_cue_input: known`` (ignored otherwise). See :class:`BackboneGeometry` for what comes back."""
        t_geo, raw, prior, normals = self.encode_geometry(images[None], alpha[None], c2w[None], intr[None])
        gauss, keep = self.inference_geometry(self.gaussians(raw[0], c2w, intr), alpha.reshape(-1) >= 0.5, c2w, intr)
        return BackboneGeometry(
            t_geo,
            raw[0],
            gauss,
            keep,
            prior[0],
            self.pixel_inputs(images, alpha, normals[0] if self.cfg.light_cue else None, input_env),
        )

    @torch.no_grad()
    def relight_one(
        self,
        recon: BackboneGeometry,
        env: torch.Tensor,
        den_c2w: torch.Tensor,
        den_intr: torch.Tensor,
        out_c2w: torch.Tensor,
        out_intr: torch.Tensor,
        height: int,
        width: int,
        generator: torch.Generator | None = None,
        guidance: float | None = None,
    ) -> torch.Tensor:
        """The baseline relighting of one reconstructed object (:meth:`reconstruct`) under one light: a full DDIM
        pass (:meth:`denoise`) at the denoising cameras den_c2w (Vd, 4, 4), den_intr (Vd, 4), then rendering out_c2w
        (Vo, 4, 4), out_intr (Vo, 4). env (He, We, 3) HDR; guidance None: ``backbone.guidance``. Returns linear
        premultiplied RGBA (Vo, H, W, 4) (the relight stage's images; ``frng bench backbone`` scores the same)."""
        assert env.dim() == 3 and env.shape[-1] == 3, env.shape
        assert den_c2w.shape[1:] == (4, 4) and den_intr.shape == (den_c2w.shape[0], 4), (den_c2w.shape, den_intr.shape)
        assert out_c2w.shape[1:] == (4, 4) and out_intr.shape == (out_c2w.shape[0], 4), (out_c2w.shape, out_intr.shape)
        sh, _ = self.denoise(
            recon.t_geo,
            recon.gaussians,
            recon.keep,
            env[None],
            den_c2w,
            den_intr,
            height,
            width,
            guidance=guidance,
            generator=generator,
            pixels=recon.pixels,
        )
        rgb, a, _ = self.render(recon.gaussians, sh, out_c2w, out_intr, height, width, recon.keep)
        return torch.cat([rgb.clamp(0.0, 1.0) ** 2.2, a], -1)

    @torch.no_grad()
    def relight(
        self,
        images: torch.Tensor,
        alpha: torch.Tensor,
        c2w: torch.Tensor,
        intr: torch.Tensor,
        envs: list[torch.Tensor],
        out_c2w: torch.Tensor,
        out_intr: torch.Tensor,
        den_c2w: torch.Tensor | None = None,
        den_intr: torch.Tensor | None = None,
        seed: int = 0,
        input_env: torch.Tensor | None = None,
    ) -> list[tuple[torch.Tensor, torch.Tensor]]:
        """The baseline relighting: geometry once, then one full denoising pass per light.

        images (V, H, W, 3), alpha (V, H, W, 1), c2w (V, 4, 4), intr (V, 4): the input views; envs: HDR maps
        (He, We, 3) each; out_c2w (Vo, 4, 4), out_intr (Vo, 4): cameras to render; input_env (He, We, 3): the
        input views' map (``light_cue_input: known`` needs it: :meth:`reconstruct`). Denoising cameras default to
        the first ``den_views`` input cameras. Returns per light (linear premultiplied RGB (Vo, H, W, 3),
        alpha (Vo, H, W, 1)); the DDIM noise is seeded per light index from ``seed``."""
        H, W = images.shape[1:3]
        if den_c2w is None:
            den_c2w, den_intr = c2w[: self.cfg.den_views], intr[: self.cfg.den_views]
        recon = self.reconstruct(images, alpha, c2w, intr, input_env)
        out = []
        for i, env in enumerate(envs):
            g = torch.Generator(device=images.device).manual_seed(seed + i)
            rgba = self.relight_one(recon, env, den_c2w, den_intr, out_c2w, out_intr, H, W, generator=g)
            out.append((rgba[..., :3], rgba[..., 3:]))
        return out


def build(cfg: dict | BackboneConfig) -> RelitLRMBackbone:
    if isinstance(cfg, dict):
        cfg = BackboneConfig.from_dict(cfg)
    return RelitLRMBackbone(cfg)


__all__ = ["BackboneGeometry", "RelitLRMBackbone", "build", "from_diffusion_space", "GEO_CHANNELS"]
