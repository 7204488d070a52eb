"""Other methods' outputs read from files (``baselines.external``; docs/baselines.md): GS-IR, R3DG, Neural Gaffer,
DiLightNet, DiffusionRenderer, LightSwitch ... run elsewhere, scored here beside F-RNG (``frng baseline-eval``).

Config: ``baselines.external`` is a list of ``{name, path, encoding: srgb | linear, family: dense | image}``; the
method's run is ``ext-{name}`` (:func:`frng.baselines.plan.external_run`). Layout of ``path``::

    {path}/{obj}/{light}/{view}.png | .exr     the method's image of test object obj, view view, under light light
    {path}/{obj}/run.json                      optional: {"fit_seconds": s, "relight_seconds_per_image": s, "views": n}

one image per target light x target view of each test object (the names of ``{results}/objects/{obj}/meta.json``);
a ``dense`` method may also give novel-view images under the object's input light (``{path}/{obj}/{input_light}/``),
scored as novel-view synthesis. Reading (:func:`read_image`):

- ``encoding``: how the stored values relate to scene light. ``srgb``: sRGB-encoded display values (decoded with the
  IEC 61966-2-1 curve, :func:`frng.io.srgb_decode`); ``linear``: linear values as stored. It applies to the colour
  channels of either container (an 8/16-bit PNG or a float EXR);
- alpha: a 4-channel PNG is straight alpha (the PNG convention: colour premultiplied here), a 4-channel EXR
  premultiplied (the convention of this project's EXRs); a 3-channel image has no mask of its own and takes the
  ground truth's alpha (its colour multiplied by it: whatever background the method composited over is dropped,
  as Neural Gaffer's evaluation masks with the ground-truth mask);
- size: an image of another size but the same aspect ratio as the ground truth is resized to it (area-averaging
  down, bilinear up, in linear premultiplied light: :func:`resize_linear`); another aspect ratio is refused
  (:class:`ExternalError`, one line naming the file). Neural Gaffer works at 256^2 and DiLightNet /
  DiffusionRenderer at 512^2, so their square outputs are resized to the dataset's square resolution;
- a missing file is an :class:`ExternalError` naming it (and the layout it was looked up in); a folder holding both
  ``{view}.png`` and ``{view}.exr`` is refused as ambiguous.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from frng import io
from frng.baselines.plan import external_run
from frng.plan.layout import RelightFolder

ENCODINGS = ("srgb", "linear")
FAMILIES = ("dense", "image")
EXTENSIONS = (".png", ".exr")


class ExternalError(ValueError):
    """An external method's folder lacks a file or holds one that cannot be scored (names the file)."""


@dataclass(frozen=True)
class ExternalMethod:
    """One ``baselines.external`` entry: ``name`` (run ``ext-{name}``), ``path`` (the folder), ``encoding``
    (``srgb`` | ``linear``), ``family`` (``dense``: a per-scene method, Table 2; ``image``: an image-based one,
    Table 3)."""

    name: str
    path: Path
    encoding: str = "srgb"
    family: str = "image"

    @classmethod
    def from_config(cls, item: Mapping, index: int = 0) -> ExternalMethod:
        """From one config entry (validated by config/schema.yaml; checked again here for direct callers)."""
        where = f"baselines.external[{index}]"
        for key in ("name", "path"):
            if key not in item:
                raise ExternalError(f"config key '{where}.{key}': required")
        enc, fam = item.get("encoding", "srgb"), item.get("family", "image")
        if enc not in ENCODINGS:
            raise ExternalError(f"config key '{where}.encoding': {enc!r}, expected one of {ENCODINGS}")
        if fam not in FAMILIES:
            raise ExternalError(f"config key '{where}.family': {fam!r}, expected one of {FAMILIES}")
        return cls(str(item["name"]), Path(item["path"]), enc, fam)

    @property
    def run(self) -> str:
        return external_run(self.name)

    def object_dir(self, oid: str) -> Path:
        return self.path / oid

    def record(self, oid: str) -> dict:
        """``{path}/{obj}/run.json`` if the method's user wrote one (its timings), else {}."""
        p = Path(RelightFolder(self.object_dir(oid)).record())
        return io.read_json(p) if p.exists() else {}

    def has_light(self, oid: str, light: str) -> bool:
        return (self.object_dir(oid) / light).is_dir()

    def image_path(self, oid: str, light: str, view: str) -> Path:
        """The one file of (obj, light, view): ``{view}.png`` or ``{view}.exr``; :class:`ExternalError` naming the
        expected file when neither (or both) exist."""
        base = self.object_dir(oid) / light / view
        found = [base.with_suffix(e) for e in EXTENSIONS if base.with_suffix(e).is_file()]
        if not found:
            raise ExternalError(
                f"{base}.png|.exr: missing (external method {self.name!r}, layout {self.path}/{{obj}}/{{light}}/"
                "{view}.png|exr)"
            )
        if len(found) > 1:
            raise ExternalError(f"{base}.png and {base}.exr: both exist (external method {self.name!r}); keep one")
        return found[0]

    def read(self, oid: str, light: str, view: str, gt: np.ndarray) -> np.ndarray:
        """The method's image of (obj, light, view) as linear premultiplied RGBA at the ground truth's size (gt:
        (H, W, 4) linear premultiplied RGBA, the reference of size and, for RGB files, of alpha)."""
        return read_image(self.image_path(oid, light, view), self.encoding, gt)


def methods(config) -> list[ExternalMethod]:
    """The config's ``baselines.external`` entries (a config mapping or :class:`frng.typedconfig.Config`); two
    entries with one name are an error."""
    sec = config.get("baselines", {}) if isinstance(config, Mapping) else config.baselines
    items = sec.get("external", []) if isinstance(sec, Mapping) else sec.external
    out, seen = [], set()
    for i, item in enumerate(items or []):
        m = ExternalMethod.from_config(item, i)
        if m.name in seen:
            raise ExternalError(f"config key 'baselines.external[{i}].name': {m.name!r} is given twice")
        seen.add(m.name)
        out.append(m)
    return out


def resize_linear(image: np.ndarray, height: int, width: int) -> np.ndarray:
    """(h, w, C) linear premultiplied -> (height, width, C): the mean of each k x k block when shrinking by an integer
    factor k (256 -> 32: exact area averaging), else scikit-image ``resize`` (order 1; Gaussian anti-aliasing when
    shrinking, bilinear when growing)."""
    from skimage.transform import resize

    h, w = image.shape[:2]
    if (h, w) == (height, width):
        return image
    if h % height == 0 and w % width == 0 and h // height == w // width:  # integer factor: exact box average
        k = h // height
        return image.reshape(height, k, width, k, -1).mean(axis=(1, 3)).astype(np.float32)
    shrink = height < h or width < w
    out = resize(image.astype(np.float64), (height, width), order=1, anti_aliasing=shrink, preserve_range=True)
    return out.astype(np.float32)


def read_image(path: str | Path, encoding: str, gt: np.ndarray) -> np.ndarray:
    """One external image -> (H, W, 4) linear premultiplied RGBA at the size of ``gt`` ((H, W, 4), linear
    premultiplied; its alpha is the mask of 3-channel files). See the module docstring for the rules. Raises
    :class:`ExternalError` naming the file (unreadable, not RGB/RGBA, another aspect ratio, NaN/inf)."""
    path = Path(path)
    if encoding not in ENCODINGS:
        raise ExternalError(f"{path}: encoding {encoding!r}, expected one of {ENCODINGS}")
    assert gt.ndim == 3 and gt.shape[-1] == 4, gt.shape
    H, W = gt.shape[:2]
    try:
        if path.suffix.lower() == ".png":
            raw = io.read_png(path)
            straight = True
        else:
            ch = io.read_exr_channels(path)
            names = [c for c in "RGBA" if c in ch]
            if names[:3] != ["R", "G", "B"]:
                raise ExternalError(f"{path}: expected R, G, B (and A) channels; has {sorted(ch)}")
            raw = np.stack([ch[c] for c in names], -1)
            straight = False
    except io.ImageError as e:
        raise ExternalError(str(e)) from e
    if raw.ndim == 2:
        raw = raw[..., None]
    if raw.shape[-1] not in (3, 4):
        raise ExternalError(f"{path}: {raw.shape[-1]} channel(s), expected RGB or RGBA")
    h, w = raw.shape[:2]
    if h * W != w * H:
        raise ExternalError(
            f"{path}: {w}x{h}, the ground truth is {W}x{H} (another aspect ratio; crop or pad it to {W}:{H})"
        )
    if not np.all(np.isfinite(raw)):
        raise ExternalError(f"{path}: contains NaN or inf")
    rgb = raw[..., :3].astype(np.float32)
    if encoding == "srgb":
        rgb = io.srgb_decode(rgb)
    if raw.shape[-1] == 4:
        a = np.clip(raw[..., 3:4], 0.0, 1.0).astype(np.float32)
        rgba = np.concatenate([rgb * a if straight else rgb, a], -1)
        return resize_linear(rgba, H, W)
    rgb = resize_linear(rgb, H, W)
    a = np.clip(gt[..., 3:4], 0.0, 1.0).astype(np.float32)
    return np.concatenate([rgb * a, a], -1)
