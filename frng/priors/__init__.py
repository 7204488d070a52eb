"""The two frozen priors F-RNG builds on: an LRM backbone and an intrinsic decomposition model (IDM).

This package only re-exports: the registries (``backbone.kind`` / ``idm.kind`` in the config -> an implementation;
plug in another with :func:`register_backbone` / :func:`register_idm`) and the IDM adapters live in
:mod:`frng.priors.registry`; the models, their config sections and caches in the submodules (their trainers in
:mod:`frng.training`).
"""

from frng.priors.registry import (
    BACKBONES,
    IDMS,
    DiffusionRendererIDMPrior,
    IDMPrior,
    LearnedIDMPrior,
    OracleIDMPrior,
    build_idm,
    freeze,
    load_backbone,
    register_backbone,
    register_idm,
    view_priors,
)

__all__ = [
    "BACKBONES",
    "IDMS",
    "DiffusionRendererIDMPrior",
    "IDMPrior",
    "LearnedIDMPrior",
    "OracleIDMPrior",
    "build_idm",
    "freeze",
    "load_backbone",
    "register_backbone",
    "register_idm",
    "view_priors",
]
