"""Reader of the curated dataset (``{results}/objects/{obj}/``), used by every later stage.

Arrays are numpy float32 unless ``torch=True``; shapes:

- images  (V, H, W, 4)  linear RGBA, premultiplied, alpha = object mask
- c2w     (V, 4, 4)     OpenCV camera-to-world (x right, y down, z forward), world Z up
- K       (V, 4)        intrinsics (fx, fy, cx, cy) in pixels
- gbuffer dict: alpha (V, H, W, 1), normal (V, H, W, 3) world unit vectors, depth (V, H, W, 1) camera z in
  world units (0 = no surface), albedo (V, H, W, 3) linear, roughness (V, H, W, 1), metallic (V, H, W, 1)

Errors name the file or key that is missing.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from frng import io
from frng.plan.layout import Layout, ObjectFolder

GBUFFER_LAYOUT = {  # key -> EXR channels (see frng.data.curate.GBUFFER_CHANNELS)
    "alpha": ("A",),
    "normal": ("normal.X", "normal.Y", "normal.Z"),
    "depth": ("depth.Z",),
    "albedo": ("albedo.R", "albedo.G", "albedo.B"),
    "roughness": ("roughness.Y",),
    "metallic": ("metallic.Y",),
}


class DatasetError(ValueError):
    """The curated data is missing or malformed; names the file/key."""


def _to(x: np.ndarray, torch: bool):
    if torch:
        import torch as _t

        return _t.from_numpy(np.ascontiguousarray(x))
    return x


@dataclass
class ObjectData:
    """One curated object. ``root`` is ``{results}/objects/{obj}``."""

    root: Path
    meta: dict

    @classmethod
    def open(cls, root: str | Path) -> ObjectData:
        root = Path(root)
        path = Path(ObjectFolder(root).meta())
        try:
            meta = io.read_json(path)
        except (FileNotFoundError, ValueError) as e:
            raise DatasetError(f"{path}: cannot read object metadata ({e}); was `frng curate` run?") from e
        for key in ("id", "views", "input_lights", "target_lights", "split", "material_class"):
            if key not in meta:
                raise DatasetError(f"{path}: missing key {key!r}")
        return cls(root, meta)

    @property
    def files(self) -> ObjectFolder:
        return ObjectFolder(self.root)

    @property
    def id(self) -> str:
        return self.meta["id"]

    @property
    def split(self) -> str:
        return self.meta["split"]

    @property
    def input_lights(self) -> list[str]:
        return list(self.meta["input_lights"])

    @property
    def target_lights(self) -> list[str]:
        return list(self.meta["target_lights"])

    def view_names(self, kind: str) -> list[str]:
        """kind: "inputs" or "targets"."""
        if kind not in self.meta["views"]:
            raise DatasetError(f"{self.files.meta()}: no views of kind {kind!r} (inputs/targets)")
        return [v["name"] for v in self.meta["views"][kind]]

    def _select(self, kind: str, views: list[str] | int | None) -> list[dict]:
        all_views = self.meta["views"][kind] if kind in self.meta["views"] else None
        if all_views is None:
            raise DatasetError(f"{self.files.meta()}: no views of kind {kind!r} (inputs/targets)")
        if views is None:
            return list(all_views)
        if isinstance(views, int):  # the first n (6 = the paper's rig)
            if views > len(all_views):
                raise DatasetError(f"{self.root}: asked for {views} {kind} views, the object has {len(all_views)}")
            return list(all_views[:views])
        by_name = {v["name"]: v for v in all_views}
        missing = [v for v in views if v not in by_name]
        if missing:
            raise DatasetError(f"{self.files.meta()}: unknown {kind} view(s) {missing}")
        return [by_name[v] for v in views]

    def cameras(self, kind: str = "inputs", views=None, torch: bool = False):
        """(c2w (V, 4, 4), K (V, 4)) of the chosen views (None = all, int = first n, list = names)."""
        sel = self._select(kind, views)
        c2w = np.asarray([v["c2w"] for v in sel], dtype=np.float32)
        K = np.asarray([v["intrinsics"] for v in sel], dtype=np.float32)
        return _to(c2w, torch), _to(K, torch)

    def images(self, kind: str, light: str, views=None, torch: bool = False):
        """RGBA images (V, H, W, 4) of ``kind`` ("inputs"/"targets") under ``light``."""
        lights = self.input_lights if kind == "inputs" else self.target_lights
        if light not in lights:
            raise DatasetError(f"{self.root}: {light!r} is not one of the object's {kind} lights {lights}")
        sel = self._select(kind, views)
        # alpha is the object's mask: an RGB-only view is refused, not read as fully opaque
        imgs = [io.read_rgba(self.files.image(kind, light, v["name"]), require_alpha=True) for v in sel]
        return _to(np.stack(imgs).astype(np.float32), torch)

    def gbuffer(self, kind: str = "inputs", views=None, torch: bool = False) -> dict:
        """G-buffers of the chosen views as a dict of (V, H, W, C) arrays (see the module docstring)."""
        sel = self._select(kind, views)
        out: dict[str, list] = {k: [] for k in GBUFFER_LAYOUT}
        for v in sel:
            path = self.files.gbuffer(v["name"])
            ch = io.read_exr_channels(path)
            for key, names in GBUFFER_LAYOUT.items():
                missing = [n for n in names if n not in ch]
                if missing:
                    raise DatasetError(f"{path}: missing G-buffer channel(s) {missing}; has {sorted(ch)}")
                out[key].append(np.stack([ch[n] for n in names], -1))
        return {k: _to(np.stack(v).astype(np.float32), torch) for k, v in out.items()}

    def envmap_path(self, light: str, results: str | Path) -> Path:
        """Path of a light's equirect EXR (lights are stored relative to the results folder)."""
        if light not in self.meta.get("lights", {}):
            raise DatasetError(f"{self.files.meta()}: unknown light {light!r}")
        return Path(results) / self.meta["lights"][light]["file"]


def open_object(results: str | Path, oid: str) -> ObjectData:
    """``ObjectData`` of ``{results}/objects/{oid}``."""
    return ObjectData.open(Layout(results).object_dir(oid))
