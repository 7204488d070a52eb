"""Curated objects as :class:`frng.priors.data.PriorObject` (what the prior trainers, caches and evaluation read).

All file access goes through the project's dataset reader :mod:`frng.data.dataset` (``open_object``: cameras,
images per light, G-buffers, env-map paths); this module only converts to the priors' tensors: RGB
(premultiplied, clamped >= 0) and alpha (clamped to [0, 1]) split, G-buffers as :class:`IntrinsicPriors`
(albedo clamped to [0, 1], every pass zeroed outside the coverage mask).
"""

from __future__ import annotations

from pathlib import Path

import torch

from frng import envmap
from frng.data import catalog
from frng.data.dataset import ObjectData, open_object
from frng.priors.data import PriorObject, Views
from frng.priors.intrinsics import IntrinsicPriors

RIG_VIEWS = 6


def _views(obj: ObjectData, kind: str, light: str) -> Views:
    t = obj.images(kind, light, None, torch=True)
    c2w, K = obj.cameras(kind, None, torch=True)
    return Views(names=obj.view_names(kind), rgb=t[..., :3].clamp_min(0.0).contiguous(),
                 alpha=t[..., 3:4].clamp(0.0, 1.0).contiguous(), c2w=c2w.float(), intr=K.float())


def read_gbuffer(obj: ObjectData) -> IntrinsicPriors:
    """G-buffers of all input views -> IntrinsicPriors (V, H, W, C); mask = coverage A."""
    g = obj.gbuffer("inputs", None, torch=True)
    return IntrinsicPriors(normal=g["normal"], depth=g["depth"], albedo=g["albedo"].clamp(0, 1),
                           roughness=g["roughness"], metallic=g["metallic"], mask=g["alpha"]).masked()


def load_object(config: dict, oid: str, with_targets: bool = True, with_gbuffer: bool = True) -> PriorObject:
    results = Path(config["results"])
    obj = open_object(results, oid)
    inputs = {l: _views(obj, "inputs", l) for l in obj.input_lights}
    targets = {l: _views(obj, "targets", l) for l in obj.target_lights} if with_targets else {}
    gb = read_gbuffer(obj) if with_gbuffer else None
    envs = {}
    for l in dict.fromkeys(obj.input_lights + obj.target_lights):
        envs[l] = torch.from_numpy(envmap.read(obj.envmap_path(l, results)))
    n_in = len(obj.view_names("inputs"))
    return PriorObject(oid, obj.split, inputs, targets, gb, envs, rig_views=min(RIG_VIEWS, n_in))


def split_ids(config: dict, split: str) -> list[str]:
    """Object ids of a split, from the dataset plan (no file scanning)."""
    return catalog.plan(config).split(split)


def load_split(config: dict, split: str, **kw) -> list[PriorObject]:
    return [load_object(config, oid, **kw) for oid in split_ids(config, split)]
