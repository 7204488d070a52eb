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
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import torch
from torch import nn

from frng import camera
from frng.nn import PatchDetokenizer, PatchTokenizer, Transformer, timestep_embedding
from frng.priors.diffusion import NoiseSchedule, from_diffusion_space, to_diffusion_space
from frng.priors.envenc import EnvTokenizer

GEO_CHANNELS = 9  # distance 1, scale 3, rotation 4, opacity 1 (RelitLRM's split)


@dataclass
class BackboneConfig:
    """Architecture of the backbone (``backbone`` config section)."""

    width: int = 256
    heads: int = 4
    geo_depth: int = 4
    app_depth: int = 2
    patch: int = 8
    sh_degree: int = 2
    env_height: int = 32
    env_patch: int = 8
    near: float = 1.0
    far: float = 4.5
    denoise_steps: int = 5
    guidance: float = 1.0
    cond_drop: float = 0.1

    @classmethod
    def from_dict(cls, d: dict) -> "BackboneConfig":
        known = {k: v for k, v in d.items() if k in cls.__dataclass_fields__}
        return cls(**known)

    def to_dict(self) -> dict:
        return asdict(self)

    @property
    def sh_coeffs(self) -> int:
        return (self.sh_degree + 1) ** 2


class RelitLRMBackbone(nn.Module):
    """Geometry transformer + appearance DiT. See the module docstring for the equations."""

    def __init__(self, cfg: BackboneConfig):
        super().__init__()
        self.cfg = cfg
        D, p = cfg.width, cfg.patch
        self.input_tokenizer = PatchTokenizer(3 + 6, D, p)
        self.geo_transformer = Transformer(D, cfg.geo_depth, cfg.heads)
        self.geo_detokenizer = PatchDetokenizer(D, GEO_CHANNELS, p)
        self.noisy_tokenizer = PatchTokenizer(3 + 6, D, p)
        self.env_tokenizer = EnvTokenizer(D, cfg.env_height, cfg.env_patch)
        self.step_mlp = nn.Sequential(nn.Linear(D, D), nn.SiLU(), nn.Linear(D, D))
        self.type_embed = nn.Parameter(torch.zeros(4, D))  # geo, light, noisy, step
        nn.init.normal_(self.type_embed, std=0.02)
        self.dit = Transformer(D, cfg.app_depth, cfg.heads)
        self.app_detokenizer = PatchDetokenizer(D, 3 * cfg.sh_coeffs, p)
        self.schedule = NoiseSchedule()

    # -- geometry ----------------------------------------------------------------------------------

    def _view_input(self, rgb: torch.Tensor, c2w: torch.Tensor, intr: torch.Tensor) -> torch.Tensor:
        """(B, V, H, W, 3) linear RGB + cameras -> (B, V, H, W, 9) = diffusion-space RGB (+) Pluecker rays."""
        B, V, H, W, _ = rgb.shape
        o, d = camera.pixel_rays(c2w.reshape(B * V, 4, 4), intr.reshape(B * V, 4), H, W)
        rays = camera.plucker(o, d).reshape(B, V, H, W, 6)
        return torch.cat([rgb if rgb.dtype != torch.bool else rgb.float(), rays], dim=-1)

    def encode_geometry(self, images: torch.Tensor, c2w: torch.Tensor, intr: torch.Tensor):
        """Input views -> geometry tokens and raw per-pixel Gaussian parameters.

        images: (B, V, H, W, 3) linear premultiplied RGB; c2w: (B, V, 4, 4); intr: (B, V, 4).
        Returns T_geo (B, V, h, w, D) and raw (B, V, H, W, 9).
        """
        x = self._view_input(to_diffusion_space(images), c2w, intr)
        tok = self.input_tokenizer(x)  # (B, V, h, w, D)
        B, V, h, w, D = tok.shape
        t_geo = self.geo_transformer(tok.reshape(B, V * h * w, D)).reshape(B, V, h, w, D)
        return t_geo, self.geo_detokenizer(t_geo)

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

    def sh_coefficients(self, t_app: torch.Tensor) -> torch.Tensor:
        """T_app (B, V, h, w, D) -> SH coefficients per Gaussian (B, V*H*W, K, 3), K = (degree + 1)^2."""
        sh = self.app_detokenizer(t_app)  # (B, V, H, W, 3K)
        B = sh.shape[0]
        return sh.reshape(B, -1, self.cfg.sh_coeffs, 3)


def build(cfg: dict | BackboneConfig) -> RelitLRMBackbone:
    if isinstance(cfg, dict):
        cfg = BackboneConfig.from_dict(cfg)
    return RelitLRMBackbone(cfg)


__all__ = ["BackboneConfig", "RelitLRMBackbone", "build", "from_diffusion_space", "GEO_CHANNELS"]
