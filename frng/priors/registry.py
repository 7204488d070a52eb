"""The priors' registries and adapters (re-exported by :mod:`frng.priors`).

Registries map config names to implementations so a user can plug in a bigger backbone or another IDM
without touching F-RNG (``backbone.kind`` / ``idm.kind`` in the config):

- ``BACKBONES[name](path, device) -> nn.Module`` loads a trained backbone file; the module must offer the
  :class:`frng.priors.backbone.RelitLRMBackbone` methods ``reconstruct``, ``denoise``, ``render``, ``relight``.
  :func:`load_backbone` freezes it (:func:`freeze`).
- ``IDMS[name](idm, backbone, results, device) -> IDMPrior`` (the config's ``idm`` and ``backbone`` sections, the
  results folder; :func:`build_idm`); an :class:`IDMPrior` turns one object's input views into
  :class:`frng.priors.intrinsics.IntrinsicPriors` (adapters: :class:`LearnedIDMPrior`, :class:`OracleIDMPrior`,
  :class:`DiffusionRendererIDMPrior`).

Register another one with :func:`register_backbone` / :func:`register_idm` (e.g. from a plugin module imported
before the stages run).
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Protocol

import torch
from torch import nn

from frng.io import CorruptFileError, load_torch
from frng.plan.sections import architecture_bounds

BACKBONES: dict[str, Callable[..., nn.Module]] = {}
IDMS: dict[str, Callable[..., IDMPrior]] = {}


def register_backbone(name: str, loader: Callable[..., nn.Module]) -> None:
    BACKBONES[name] = loader


def register_idm(name: str, factory: Callable[..., IDMPrior]) -> None:
    IDMS[name] = factory


def freeze(module: nn.Module) -> nn.Module:
    """Eval mode, ``requires_grad=False`` on every parameter, and ``train()`` pinned to eval (so F-RNG code calling
    ``model.train()`` on a parent module cannot switch the prior back to training behaviour)."""
    module.eval()
    for p in module.parameters():
        p.requires_grad_(False)

    def _stay_eval(mode: bool = True):
        return nn.Module.train(module, False)

    module.train = _stay_eval  # type: ignore[method-assign]
    return module


def _load_relitlrm(path: str | Path, device: torch.device | str = "cpu") -> nn.Module:
    from frng.priors.backbone import RelitLRMBackbone
    from frng.priors.backbone_config import BackboneConfig

    state = load_torch(path, "backbone model file", architecture_bounds())
    model = RelitLRMBackbone(BackboneConfig.from_saved(state["config"]))
    model.load_state_dict(state["state_dict"])
    return model.to(device)


def load_backbone(path: str | Path, device: torch.device | str = "cpu", kind: str | None = None) -> nn.Module:
    """Load a trained backbone file (``kind`` from the file unless given) and freeze it."""
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"{path}: backbone model file does not exist; run `frng backbone-train` first")
    if kind is None:
        state = load_torch(
            path, "backbone model file", architecture_bounds()
        )  # weights_only: a crafted model.pt runs nothing
        if not isinstance(state, dict):
            raise CorruptFileError(f"{path}: not a backbone model file (a {type(state).__name__})")
        kind = state.get("kind", "relitlrm")
    if kind not in BACKBONES:
        raise KeyError(f"unknown backbone kind {kind!r}; registered: {sorted(BACKBONES)}")
    return freeze(BACKBONES[kind](path, device))


class IDMPrior(Protocol):
    kind: str

    def priors(self, oid: str, views, gbuffer=None):  # -> IntrinsicPriors
        """views: :class:`frng.priors.dataset.Views` (the object's input views, in order); gbuffer: the object's
        G-buffers of the same views (IntrinsicPriors) where available."""


def view_priors(idm: IDMPrior, obj, light: str, rows):
    """The priors of ``idm`` for the input views ``rows`` (indices into the views of ``obj``, a
    :class:`frng.priors.dataset.PriorObject`, under input light ``light``), made from exactly those views.

    The IDM attends across the views it is given and cuts their visual hull, so a view's priors depend on the
    others: priors made from more of the object's views and cut afterwards would hand a run the other views'
    silhouettes and colours (docs/priors.md). Returns IntrinsicPriors (len(rows), H, W, C) on the IDM's device."""
    rows = list(rows)
    gbuffer = obj.gbuffer.select(torch.as_tensor(rows)) if obj.gbuffer is not None else None
    return idm.priors(obj.id, obj.inputs[light].select(rows), gbuffer)


class LearnedIDMPrior:
    kind = "learned"

    def __init__(self, model_path: str | Path, device: torch.device | str = "cpu"):
        from frng.priors.idm import IDMConfig, LearnedIDM

        model_path = Path(model_path)
        if not model_path.exists():
            raise FileNotFoundError(f"{model_path}: IDM model file does not exist; run `frng idm-train` first")
        state = load_torch(model_path, "IDM model file", architecture_bounds())
        self.model = LearnedIDM(IDMConfig.from_dict(state["config"]))
        self.model.load_state_dict(state["state_dict"])
        self.model = freeze(self.model.to(device))
        self.device = device
        self.model_path = model_path

    def priors(self, oid, views, gbuffer=None):
        d = self.device
        return self.model.predict(views.rgb.to(d), views.alpha.to(d), views.c2w.to(d), views.intr.to(d)).to("cpu")


class OracleIDMPrior:
    kind = "oracle"

    def priors(self, oid, views, gbuffer=None):
        if gbuffer is None:
            raise ValueError(f"object {oid}: the oracle IDM needs the object's G-buffers")
        return gbuffer


class DiffusionRendererIDMPrior:
    kind = "diffusion-renderer"

    def __init__(self, folder: str | Path, near: float, far: float, normal_space: str, depth_invert: bool):
        self.folder, self.near, self.far = Path(folder), near, far
        self.normal_space, self.depth_invert = normal_space, depth_invert

    def priors(self, oid, views, gbuffer=None):
        from frng.priors.diffusion_renderer import read_priors

        return read_priors(
            self.folder / oid, views.c2w, views.alpha, self.near, self.far, self.normal_space, self.depth_invert
        )


def _learned(idm, backbone, results: str | Path, device="cpu") -> IDMPrior:
    from frng.plan.layout import Layout

    return LearnedIDMPrior(Path(Layout(results).idm_model()), device)


def _oracle(idm, backbone, results: str | Path, device="cpu") -> IDMPrior:
    return OracleIDMPrior()


def _diffusion_renderer(idm, backbone, results: str | Path, device="cpu") -> IDMPrior:
    if not idm.diffusion_renderer_dir:
        raise ValueError("config key 'idm.diffusion_renderer_dir': required for idm.kind = diffusion-renderer")
    return DiffusionRendererIDMPrior(
        idm.diffusion_renderer_dir, backbone.near, backbone.far, idm.normal_space, idm.depth_invert
    )


def build_idm(idm, backbone, results: str | Path, device="cpu", kind: str | None = None) -> IDMPrior:
    """The IDM of ``kind`` (default ``idm.kind``) from the config's ``idm`` section
    (:class:`frng.training.idm.IDMSection`), its ``backbone`` section
    (:class:`frng.training.backbone.BackboneSection`: near/far) and the results folder (the learned IDM's model
    file). The sections are not annotated: their modules import this one's package."""
    kind = kind or idm.kind
    if kind not in IDMS:
        raise KeyError(f"unknown IDM kind {kind!r}; registered: {sorted(IDMS)}")
    return IDMS[kind](idm, backbone, results, device)


register_backbone("relitlrm", _load_relitlrm)
register_idm("learned", _learned)
register_idm("oracle", _oracle)
register_idm("diffusion-renderer", _diffusion_renderer)
