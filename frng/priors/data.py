"""In-memory views of one curated object, in the tensors the priors train and run on.

:class:`Views` is a set of images of one object under one light at a set of cameras; :class:`PriorObject` holds
everything the priors read of one object (input views per input light, target views per target light, G-buffers
of the input views, env maps). :func:`load_object` reads it from the curated dataset through the project's
reader (:mod:`frng.data.dataset`), so no stage guesses file paths.

Image tensors: linear premultiplied RGB (V, H, W, 3) and alpha (V, H, W, 1), float32; cameras c2w (V, 4, 4)
OpenCV, intrinsics (V, 4) = fx, fy, cx, cy; env maps (He, We, 3) linear HDR.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import torch

from frng.priors.intrinsics import IntrinsicPriors


@dataclass
class Views:
    names: list[str]
    rgb: torch.Tensor
    alpha: torch.Tensor
    c2w: torch.Tensor
    intr: torch.Tensor

    def select(self, idx) -> "Views":
        idx = list(idx)
        it = torch.as_tensor(idx, dtype=torch.long)
        return Views([self.names[i] for i in idx], self.rgb[it], self.alpha[it], self.c2w[it], self.intr[it])

    def __len__(self) -> int:
        return len(self.names)


@dataclass
class PriorObject:
    id: str
    split: str
    inputs: dict[str, Views]                   # input light -> all input views (rig first, then extras)
    targets: dict[str, Views]                  # target light -> target views
    gbuffer: IntrinsicPriors | None            # G-buffers of all input views (same order), or None
    envs: dict[str, torch.Tensor] = field(default_factory=dict)  # light name -> (He, We, 3)
    rig_views: int = 6                         # the first rig_views input views are the paper's rig

    @property
    def input_lights(self) -> list[str]:
        return list(self.inputs)

    @property
    def target_lights(self) -> list[str]:
        return list(self.targets)
