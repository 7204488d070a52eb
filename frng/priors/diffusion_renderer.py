"""IDM kind ``diffusion-renderer``: read DiffusionRenderer's inverse-rendering outputs into IDM prior tensors.

DiffusionRenderer (Liang et al. 2025) cannot be run here; users who run it themselves on an object's input views
(as one video, in input-view order) point ``idm.diffusion_renderer_dir`` at a folder per object,
``{idm.diffusion_renderer_dir}/{obj}/``, holding its output files as that project writes them:

    <chunk>.<frame>.<pass>.png        one 8-bit PNG per pass and frame
    pass in {basecolor, metallic, roughness, normal, depth}

``<chunk>`` and ``<frame>`` are integers (zero padding optional). Frames are ordered by (chunk, frame): the
k-th frame in that order is the k-th input view. Every (frame, pass) must be present.

Conversions (8-bit value ``q``, ``x = q / 255``), into the conventions of :mod:`frng.priors.intrinsics`:

- ``basecolor``: sRGB-encoded display values -> linear albedo with the sRGB decoding (colour-science).
- ``roughness``, ``metallic``: linear scalars in [0, 1]; an RGB file uses its channel mean.
- ``normal``: ``n = 2x - 1`` in DiffusionRenderer's camera frame (OpenGL: x right, y up, z towards the viewer),
  flipped to OpenCV (x, -y, -z), rotated to world by the view's c2w, re-normalised. ``normal_space = "world"``
  takes the file as world-space instead.
- ``depth``: relative depth, min-max normalised per video, bright = far (``depth_invert`` for bright = near);
  mapped affinely to [near, far] camera z. It is only a relative prior: no metric scale is claimed.
- ``mask``: DiffusionRenderer writes none; the input views' alpha is used.

Files at another resolution than the input views are resized (bilinear, antialiased). Missing or unreadable files
raise :class:`DiffusionRendererError` naming the file and the pass.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F

from frng import io
from frng.priors.intrinsics import IntrinsicPriors

PASSES = ("basecolor", "metallic", "roughness", "normal", "depth")
_NAME = re.compile(r"^(?P<chunk>\d+)\.(?P<frame>\d+)\.(?P<pass>[a-z_]+)\.png$")


class DiffusionRendererError(ValueError):
    """A DiffusionRenderer output file is missing or unusable; the message names the file and the pass."""


def list_frames(folder: str | Path) -> list[tuple[str, str]]:
    """Sorted (chunk, frame) name pairs (as written, padding kept) found for any pass in ``folder``."""
    folder = Path(folder)
    if not folder.is_dir():
        raise DiffusionRendererError(f"{folder}: DiffusionRenderer output folder does not exist")
    keys = set()
    for p in folder.iterdir():
        m = _NAME.match(p.name)
        if m and m["pass"] in PASSES:
            keys.add((m["chunk"], m["frame"]))
    return sorted(keys, key=lambda k: (int(k[0]), int(k[1])))


def _read(path: Path, pass_: str, size: tuple[int, int]) -> np.ndarray:
    if not path.exists():
        raise DiffusionRendererError(f"{path}: missing DiffusionRenderer '{pass_}' pass file")
    try:
        img = io.read_png(path)
    except io.ImageError as e:
        raise DiffusionRendererError(f"{path}: unreadable DiffusionRenderer '{pass_}' pass file ({e})") from e
    if img.ndim == 2:
        img = img[..., None]
    img = img[..., :3]  # drop alpha if any
    if pass_ in ("basecolor", "normal") and img.shape[-1] != 3:
        raise DiffusionRendererError(f"{path}: '{pass_}' pass must be RGB, got {img.shape[-1]} channel(s)")
    if not np.all(np.isfinite(img)):
        raise DiffusionRendererError(f"{path}: '{pass_}' pass has non-finite values")
    if img.shape[:2] != size:
        t = torch.from_numpy(np.ascontiguousarray(img)).permute(2, 0, 1)[None]
        t = F.interpolate(t, size=size, mode="bilinear", antialias=True, align_corners=False)
        img = t[0].permute(1, 2, 0).numpy()
    return img.astype(np.float32)


def read_priors(
    folder: str | Path,
    c2w: torch.Tensor,
    alpha: torch.Tensor,
    near: float,
    far: float,
    normal_space: str = "camera-opengl",
    depth_invert: bool = False,
) -> IntrinsicPriors:
    """Read one object's DiffusionRenderer outputs for V input views.

    c2w: (V, 4, 4) OpenCV cameras of the input views (frame order); alpha: (V, H, W, 1) their masks.
    Returns IntrinsicPriors with (V, H, W, C) passes, masked.
    """
    folder = Path(folder)
    V, H, W = alpha.shape[:3]
    frames = list_frames(folder)
    if len(frames) < V:
        raise DiffusionRendererError(
            f"{folder}: found {len(frames)} DiffusionRenderer frame(s), need one per input view ({V})"
        )
    frames = frames[:V]
    per_pass: dict[str, list[np.ndarray]] = {p: [] for p in PASSES}
    for chunk, frame in frames:
        for p in PASSES:
            per_pass[p].append(_read(folder / f"{chunk}.{frame}.{p}.png", p, (H, W)))
    arr = {p: torch.from_numpy(np.stack(v)) for p, v in per_pass.items()}  # (V, H, W, C)

    albedo = torch.from_numpy(io.srgb_decode(arr["basecolor"].numpy()))
    rough = arr["roughness"].mean(-1, keepdim=True)
    metal = arr["metallic"].mean(-1, keepdim=True)
    n = 2.0 * arr["normal"] - 1.0
    if normal_space == "camera-opengl":
        n = n * torch.tensor([1.0, -1.0, -1.0])
        n = (c2w[:, None, None, :3, :3].float() @ n.unsqueeze(-1)).squeeze(-1)
    elif normal_space != "world":
        raise ValueError(f"idm.normal_space must be 'camera-opengl' or 'world', got {normal_space!r}")
    n = F.normalize(n, dim=-1, eps=1e-6)
    d = arr["depth"].mean(-1, keepdim=True)
    if depth_invert:
        d = 1.0 - d
    depth = near + d * (far - near)
    return IntrinsicPriors(
        normal=n, depth=depth, albedo=albedo, roughness=rough, metallic=metal, mask=alpha.float()
    ).masked()
