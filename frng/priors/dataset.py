"""Curated objects in the tensors the priors train and run on (what the prior trainers, caches and evaluation read).

:class:`Views` is a set of images of one object under one light at a set of cameras; :class:`PriorObject` holds
everything the priors read of one object (input views per input light, target views per target light, G-buffers
of the input views, env maps). :func:`load_object` / :func:`load_split` read them from the curated dataset.

All file access goes through the project's dataset reader :mod:`frng.data.dataset` (``open_object``: cameras,
images per light, G-buffers, env-map paths), so no stage guesses file paths; this module only converts to the
priors' tensors: RGB (premultiplied, clamped >= 0) and alpha (clamped to [0, 1]) split, G-buffers as
:class:`IntrinsicPriors` (albedo clamped to [0, 1], every pass zeroed outside the coverage mask).

Image tensors: linear premultiplied RGB (V, H, W, 3) and alpha (V, H, W, 1), float32; cameras c2w (V, 4, 4)
OpenCV, intrinsics (V, 4) = fx, fy, cx, cy; env maps (He, We, 3) linear HDR.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import torch

from frng.data.dataset import ObjectData, open_object
from frng.priors.intrinsics import IntrinsicPriors
from frng.render import envmap

RIG_VIEWS = 6


@dataclass
class Views:
    names: list[str]
    rgb: torch.Tensor
    alpha: torch.Tensor
    c2w: torch.Tensor
    intr: torch.Tensor

    def select(self, idx) -> Views:
        idx = list(idx)
        it = torch.as_tensor(idx, dtype=torch.long)
        return Views([self.names[i] for i in idx], self.rgb[it], self.alpha[it], self.c2w[it], self.intr[it])

    def __len__(self) -> int:
        return len(self.names)


@dataclass
class PriorObject:
    id: str
    split: str
    inputs: dict[str, Views]  # input light -> all input views (rig first, then extras)
    targets: dict[str, Views]  # target light -> target views
    gbuffer: IntrinsicPriors | None  # G-buffers of all input views (same order), or None
    envs: dict[str, torch.Tensor] = field(default_factory=dict)  # light name -> (He, We, 3)
    rig_views: int = 6  # the first rig_views input views are the paper's rig

    @property
    def input_lights(self) -> list[str]:
        return list(self.inputs)

    @property
    def target_lights(self) -> list[str]:
        return list(self.targets)


def _views(obj: ObjectData, kind: str, light: str) -> Views:
    t = obj.images(kind, light, None, torch=True)
    c2w, K = obj.cameras(kind, None, torch=True)
    return Views(
        names=obj.view_names(kind),
        rgb=t[..., :3].clamp_min(0.0).contiguous(),
        alpha=t[..., 3:4].clamp(0.0, 1.0).contiguous(),
        c2w=c2w.float(),
        intr=K.float(),
    )


def read_gbuffer(obj: ObjectData, kind: str = "inputs", views: list[str] | None = None) -> IntrinsicPriors:
    """G-buffers of the ``kind`` views ``views`` (default: all input views) -> IntrinsicPriors (V, H, W, C); mask =
    coverage A."""
    g = obj.gbuffer(kind, views, torch=True)
    return IntrinsicPriors(
        normal=g["normal"],
        depth=g["depth"],
        albedo=g["albedo"].clamp(0, 1),
        roughness=g["roughness"],
        metallic=g["metallic"],
        mask=g["alpha"],
    ).masked()


def load_object(results: str | Path, oid: str, with_targets: bool = True, with_gbuffer: bool = True) -> PriorObject:
    """Curated object ``oid`` under ``results``: its input (and target) views, env maps and G-buffer."""
    results = Path(results)
    obj = open_object(results, oid)
    inputs = {l: _views(obj, "inputs", l) for l in obj.input_lights}
    targets = {l: _views(obj, "targets", l) for l in obj.target_lights} if with_targets else {}
    gb = read_gbuffer(obj) if with_gbuffer else None
    envs = {}
    for l in dict.fromkeys(obj.input_lights + obj.target_lights):
        envs[l] = torch.from_numpy(envmap.read(obj.envmap_path(l, results)))
    n_in = len(obj.view_names("inputs"))
    return PriorObject(oid, obj.split, inputs, targets, gb, envs, rig_views=min(RIG_VIEWS, n_in))


def load_split(results: str | Path, ids: list[str], **kw) -> list[PriorObject]:
    """The curated objects ``ids`` under ``results`` (:func:`load_object` with ``kw``): a split of the dataset plan,
    ``frng.plan.catalog.plan(config).split(name)`` (no file scanning)."""
    return [load_object(results, oid, **kw) for oid in ids]
