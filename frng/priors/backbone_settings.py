"""Inference settings of a trained backbone that the pipeline does not vary, for experiments on the baseline
(``frng bench backbone``): the denoiser's guidance scale, where the light cue reads its normals, and whether the
per-pixel head's learned output is kept.

- ``guidance``: classifier-free guidance scale (None: the model's ``backbone.guidance``);
- ``normals``: ``hull`` (the visual hull's, what the model uses), ``gbuffer`` (the renderer's ground-truth normals:
  an oracle) or ``depth`` (finite differences of the backbone's per-pixel Gaussians,
  :func:`frng.priors.surfels.grid_normals`);
- ``head``: ``learned`` or ``zero`` (its SH and gain output set to 0: the render is the input colour times the
  closed-form light cue alone, :meth:`frng.priors.backbone.RelitLRMBackbone.sh_coefficients`)."""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import nn

from frng.priors.backbone import BackboneGeometry, RelitLRMBackbone

NORMALS = ("hull", "gbuffer", "depth")
HEADS = ("learned", "zero")


@dataclass(frozen=True)
class BackboneSettings:
    guidance: float | None = None
    normals: str = NORMALS[0]
    head: str = HEADS[0]

    def __post_init__(self):
        if self.normals not in NORMALS:
            raise ValueError(f"normals must be one of {NORMALS}, got {self.normals!r}")
        if self.head not in HEADS:
            raise ValueError(f"head must be one of {HEADS}, got {self.head!r}")

    @classmethod
    def parse(cls, settings: dict[str, str]) -> BackboneSettings:
        """Settings given as text (``{"guidance": "2", "normals": "gbuffer"}``); ValueError naming a bad one."""
        unknown = sorted(set(settings) - {"guidance", "normals", "head"})
        if unknown:
            raise ValueError(f"unknown setting(s) {unknown}: guidance, normals, head")
        guidance = None
        if "guidance" in settings:
            try:
                guidance = float(settings["guidance"])
            except ValueError:
                raise ValueError(f"guidance must be a number, got {settings['guidance']!r}") from None
        return cls(guidance, settings.get("normals", NORMALS[0]), settings.get("head", HEADS[0]))

    def describe(self) -> str:
        """The settings that differ from the model's own, as text ("as trained" when none)."""
        parts = [f"guidance {self.guidance:g}"] if self.guidance is not None else []
        parts += [f"normals {self.normals}"] if self.normals != NORMALS[0] else []
        parts += [f"head {self.head}"] if self.head != HEADS[0] else []
        return ", ".join(parts) or "as trained"

    def apply(self, backbone: RelitLRMBackbone) -> RelitLRMBackbone:
        """The loaded ``backbone`` set up for these settings (changed in place: load one per setting)."""
        if self.normals != "hull" and not backbone.cfg.light_cue:
            raise ValueError(f"normals={self.normals} needs a backbone with the light cue (backbone.light_cue)")
        if self.head == "zero":
            if backbone.pixel_head is None:
                raise ValueError("head=zero needs a backbone with the per-pixel head (backbone.cues: true)")
            backbone.pixel_head = _ZeroHead(backbone.pixel_head)
        return backbone

    def reconstruction(
        self,
        backbone: RelitLRMBackbone,
        recon: BackboneGeometry,
        rgb: torch.Tensor,
        alpha: torch.Tensor,
        c2w: torch.Tensor,
        input_env: torch.Tensor,
        gbuffer_normals: torch.Tensor | None = None,
    ) -> BackboneGeometry:
        """``recon`` (:meth:`~frng.priors.backbone.RelitLRMBackbone.reconstruct` of rgb (V, H, W, 3), alpha
        (V, H, W, 1) at c2w (V, 4, 4) under input_env (He, We, 3)) with the light cue reading these settings'
        normals; gbuffer_normals (V, H, W, 3) world frame, required by ``normals=gbuffer``."""
        if self.normals == "hull":
            return recon
        V = rgb.shape[0]
        if self.normals == "gbuffer":
            if gbuffer_normals is None:
                raise ValueError("normals=gbuffer needs the object's G-buffer normals")
            assert gbuffer_normals.shape == rgb.shape, (gbuffer_normals.shape, rgb.shape)
            n = gbuffer_normals.float()
        else:
            from frng.priors.surfels import grid_normals

            n = grid_normals(recon.gaussians.means[: alpha.numel()], alpha.reshape(-1) >= 0.5, c2w)
        assert n.shape[0] == V, n.shape
        return recon._replace(pixels=backbone.pixel_inputs(rgb, alpha, n * (alpha >= 0.5), input_env))


class _ZeroHead(nn.Module):
    """A per-pixel head whose output is zero (``head=zero``), the learned head's shape."""

    def __init__(self, head: nn.Module):
        super().__init__()
        self.head = head

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return torch.zeros_like(self.head(x))
