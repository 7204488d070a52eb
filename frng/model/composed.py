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

from dataclasses import asdict, dataclass, replace
from pathlib import Path

import torch
from torch import nn

from frng import io
from frng.device import bf16_ok
from frng.gaussians import GaussianDecodeConfig, Gaussians
from frng.model.composed_config import FRNGConfig
from frng.model.coverage import COVERAGE_PREFIX, CoverageHead
from frng.model.depth import DepthHead
from frng.model.fine_geometry import FineGeometry, FineGeometryConfig, fine_keep_mask
from frng.model.materialformer import (
    MaterialHead,
    decode_pbr,
    kept_rows,
    to_sequence,
)
from frng.model.opacity import GEOMETRY_CHANNELS, OpacityHead, geometry_inputs
from frng.model.pixel_head import (
    PixelHead,
    kept_pixel_rows,
    normal_start_projection,
    pixel_channels,
    pixel_map,
    pixel_normal_index,
)
from frng.model.saliency import patch_scores, saliency_map, select_top_k
from frng.model.tokenizers import PriorTokenizer, stack_priors
from frng.plan.sections import architecture_bounds
from frng.render import RasterConfig, envmap, rasterize
from frng.render.decoder import shade_decoder
from frng.render.shading import (
    COSINE_NORMAL,
    GGX_NORMAL,
    NeuralDecoder,
    ShadingConfig,
    ggx_shade,
    smooth_normals,
)

MODEL_KIND = "frng"


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


__all__ = ["FRNG", "Reconstruction"]
