"""Read curated objects into :class:`frng.priors.data.PriorObject` (the layout written by ``frng curate``).

``{results}/objects/{obj}/``: ``meta.json`` (cameras under ``views.inputs`` / ``views.targets``, lights,
split), ``inputs/{light}/{view}.exr`` and ``targets/{light}/{view}.exr`` (RGBA premultiplied linear),
``gbuffer/{view}.exr`` (channels ``A, normal.X/Y/Z, depth.Z, albedo.R/G/B, roughness.Y, metallic.Y``) and the
env maps ``{results}/envmaps/{light}.exr``. This is a small reader local to the priors (the project-wide
reader is :mod:`frng.data.dataset` once it exists); it only reads the documented files.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from frng import envmap, io
from frng.data import catalog
from frng.priors.data import PriorObject, Views
from frng.priors.intrinsics import IntrinsicPriors

RIG_VIEWS = 6


def _views(folder: Path, cams: list[dict]) -> Views:
    imgs = np.stack([io.read_rgba(folder / f"{c['name']}.exr") for c in cams])
    t = torch.from_numpy(imgs)
    return Views(
        names=[c["name"] for c in cams],
        rgb=t[..., :3].clamp_min(0.0).contiguous(),
        alpha=t[..., 3:4].clamp(0.0, 1.0).contiguous(),
        c2w=torch.tensor(np.array([c["c2w"] for c in cams]), dtype=torch.float32),
        intr=torch.tensor(np.array([c["intrinsics"] for c in cams]), dtype=torch.float32),
    )


def read_gbuffer(folder: Path, names: list[str]) -> IntrinsicPriors:
    """G-buffers of the named views -> IntrinsicPriors (V, H, W, C); mask = coverage A."""
    chans = ["normal.X", "normal.Y", "normal.Z", "depth.Z", "albedo.R", "albedo.G", "albedo.B",
             "roughness.Y", "metallic.Y", "A"]
    g = torch.from_numpy(np.stack([io.read_exr(folder / f"{n}.exr", chans) for n in names]))
    return IntrinsicPriors(normal=g[..., 0:3], depth=g[..., 3:4], albedo=g[..., 4:7].clamp(0, 1),
                           roughness=g[..., 7:8], metallic=g[..., 8:9], mask=g[..., 9:10]).masked()


def load_object(config: dict, oid: str, with_targets: bool = True, with_gbuffer: bool = True) -> PriorObject:
    results = Path(config["results"])
    root = results / "objects" / oid
    meta = io.read_json(root / "meta.json")
    cams_in = meta["views"]["inputs"]
    cams_tg = meta["views"]["targets"]
    inputs = {l: _views(root / "inputs" / l, cams_in) for l in meta["input_lights"]}
    targets = {l: _views(root / "targets" / l, cams_tg) for l in meta["target_lights"]} if with_targets else {}
    gb = read_gbuffer(root / "gbuffer", [c["name"] for c in cams_in]) if with_gbuffer else None
    envs = {}
    for l in dict.fromkeys(meta["input_lights"] + meta["target_lights"]):
        envs[l] = torch.from_numpy(envmap.read(results / "envmaps" / f"{l}.exr"))
    return PriorObject(oid, meta["split"], inputs, targets, gb, envs, rig_views=min(RIG_VIEWS, len(cams_in)))


def split_ids(config: dict, split: str) -> list[str]:
    """Object ids of a split, from the dataset plan (no file scanning)."""
    return catalog.plan(config).split(split)


def load_split(config: dict, split: str, **kw) -> list[PriorObject]:
    return [load_object(config, oid, **kw) for oid in split_ids(config, split)]
