"""The per-scene baselines' shared optimisation loop (``3dgs``: :mod:`frng.baselines.splat3d`, ``gsir``:
:mod:`frng.baselines.gsir`), over the project's own differentiable rasterizer (:func:`frng.render.rasterize`; its
``torch`` tile backend on a CPU, ``gsplat`` on CUDA).

What is shared, as 3DGS's ``train.py`` (Kerbl et al. 2023, graphdeco-inria/gaussian-splatting) does it:

- :class:`GaussianSet`: per-Gaussian parameters (pre-activation: log-scales, opacity logits) each in its own Adam
  group (eps 1e-15), with the optimiser state kept in step when Gaussians are appended (densification: zero moments)
  or removed (pruning), or a parameter is replaced (opacity reset);
- :func:`optimise`: ``steps`` steps; each renders ``views_per_step`` training views drawn from a shuffled stack
  (every view once before any repeats, from a seeded generator: the fit is deterministic for a seed and a thread
  count), L1 + D-SSIM (lambda 0.2, an 11 px Gaussian window of sigma 1.5, :func:`photometric_loss`), one Adam step;
  progress on stderr; returns the loss / PSNR curve (``loss.csv``);
- :class:`Densifier`: 3DGS's adaptive density control: the norm of each Gaussian's view-space (NDC) positional
  gradient averaged over the steps it was visible in; above ``densify_grad`` small Gaussians are cloned and large
  ones split in two (scales / 1.6, positions drawn from the Gaussian); prune at opacity < 0.005, a large screen radius
  (after the first reset; :class:`Densifier`) and world size > 0.1 x the cameras' extent; opacity reset to <= 0.01; the schedule
  (from / until / every / reset) as fractions of the stage's steps (3DGS: 500 / 15k / 100 / 3k of 30k).

The view-space gradient: with the ``torch`` backend the 2D means of :func:`frng.render.project.project_gaussians`
keep their gradient (exact, as 3DGS's ``viewspace_points``); with ``gsplat`` the 3D means' gradient is taken into
each view's image plane (``z / f`` per axis; the covariance's share of it, which 3DGS leaves out, stays in).

Images are linear, premultiplied by alpha (composited over black), ``(V, H, W, C)`` like the rasterizer's output.
"""

from __future__ import annotations

import math
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
import torch
import torch.nn.functional as F

from frng.render.project import project_gaussians
from frng.render.raster import RasterConfig, rasterize, resolve_backend
from frng.render.tiles import TILE_KERNELS, rasterize_tiles

LAMBDA_DSSIM = 0.2  # 3DGS's lambda_dssim
SSIM_WINDOW, SSIM_SIGMA = 11, 1.5  # 3DGS utils/loss_utils.py
ADAM_EPS = 1e-15  # 3DGS's training_setup
MIN_OPACITY = 0.005  # 3DGS's prune threshold
RESET_OPACITY = 0.01  # 3DGS's reset_opacity: min(opacity, 0.01)
MAX_SCREEN_FRACTION = 0.1  # screen-radius prune (after the first reset), a fraction of the width (see Densifier)
MAX_WORLD_FRACTION = 0.1  # 3DGS: prune Gaussians larger than 0.1 x the cameras' extent
PERCENT_DENSE = 0.01  # 3DGS: clone below, split above this fraction of the extent
SPLIT_N = 2


# -- data ----------------------------------------------------------------------------------------------------------


@dataclass
class TrainViews:
    """The training views of one fit: ``names`` (V), ``c2w`` (V, 4, 4) OpenCV camera-to-world, ``intr`` (V, 4)
    (fx, fy, cx, cy), ``rgb`` (V, H, W, 3) linear premultiplied, ``alpha`` (V, H, W, 1) the object's mask."""

    names: list[str]
    c2w: torch.Tensor
    intr: torch.Tensor
    rgb: torch.Tensor
    alpha: torch.Tensor

    def __post_init__(self):
        V = len(self.names)
        assert self.c2w.shape == (V, 4, 4), self.c2w.shape
        assert self.intr.shape == (V, 4), self.intr.shape
        assert self.rgb.ndim == 4 and self.rgb.shape[0] == V and self.rgb.shape[-1] == 3, self.rgb.shape
        assert self.alpha.shape == self.rgb.shape[:3] + (1,), self.alpha.shape

    @property
    def size(self) -> tuple[int, int]:
        return int(self.rgb.shape[1]), int(self.rgb.shape[2])

    def __len__(self) -> int:
        return len(self.names)

    def extent(self) -> float:
        """3DGS's ``cameras_extent``: 1.1 x the largest distance of a camera centre from their mean."""
        c = self.c2w[:, :3, 3]
        return 1.1 * float((c - c.mean(0)).norm(dim=-1).max().clamp_min(1e-6))


# -- losses --------------------------------------------------------------------------------------------------------


def _window(device, dtype) -> torch.Tensor:
    x = torch.arange(SSIM_WINDOW, device=device, dtype=dtype) - SSIM_WINDOW // 2
    g = torch.exp(-(x * x) / (2 * SSIM_SIGMA**2))
    g = g / g.sum()
    return g[:, None] * g[None, :]


def ssim(pred: torch.Tensor, gt: torch.Tensor) -> torch.Tensor:
    """Mean SSIM of pred, gt (V, H, W, C) (differentiable; 3DGS's ``ssim``: Gaussian window, zero padding)."""
    assert pred.shape == gt.shape and pred.ndim == 4, (pred.shape, gt.shape)
    C = pred.shape[-1]
    x, y = pred.permute(0, 3, 1, 2), gt.permute(0, 3, 1, 2)
    w = _window(pred.device, pred.dtype)[None, None].expand(C, 1, SSIM_WINDOW, SSIM_WINDOW)

    def blur(t):
        return F.conv2d(t, w, padding=SSIM_WINDOW // 2, groups=C)

    mx, my = blur(x), blur(y)
    sxx, syy, sxy = blur(x * x) - mx * mx, blur(y * y) - my * my, blur(x * y) - mx * my
    c1, c2 = 0.01**2, 0.03**2
    s = ((2 * mx * my + c1) * (2 * sxy + c2)) / ((mx * mx + my * my + c1) * (sxx + syy + c2))
    return s.mean()


def photometric_loss(pred: torch.Tensor, gt: torch.Tensor, lambda_dssim: float = LAMBDA_DSSIM) -> torch.Tensor:
    """3DGS's loss (1 - lambda) L1 + lambda (1 - SSIM) of pred, gt (V, H, W, 3)."""
    return (1.0 - lambda_dssim) * (pred - gt).abs().mean() + lambda_dssim * (1.0 - ssim(pred, gt))


def psnr(pred: torch.Tensor, gt: torch.Tensor) -> float:
    """PSNR (dB, peak 1) of pred, gt (..., 3), values clamped to [0, 1] as written images are scored."""
    mse = float(((pred.detach().clamp(0, 1) - gt.detach().clamp(0, 1)) ** 2).mean())
    return 10.0 * math.log10(1.0 / max(mse, 1e-12))


# -- Gaussians and their optimiser ----------------------------------------------------------------------------------


def inverse_sigmoid(x: torch.Tensor) -> torch.Tensor:
    x = x.clamp(1e-6, 1 - 1e-6)
    return torch.log(x / (1 - x))


class GaussianSet:
    """Per-Gaussian parameters ``params`` name -> (N, ...) tensor (``means`` (N, 3), ``log_scales`` (N, 3),
    ``quats`` (N, 4), ``opacity`` (N, 1) logits, plus the method's own), each one Adam group with its own lr."""

    GEOMETRY = ("means", "log_scales", "quats", "opacity")

    def __init__(self, params: dict[str, torch.Tensor], lrs: dict[str, float]):
        N = params["means"].shape[0]
        for k, v in params.items():
            assert v.shape[0] == N, (k, v.shape, N)
        assert params["means"].shape == (N, 3) and params["quats"].shape == (N, 4), "means (N, 3), quats (N, 4)"
        assert params["log_scales"].shape == (N, 3) and params["opacity"].shape == (N, 1), "scales, opacity"
        self.params = {k: torch.nn.Parameter(v.detach().clone().float()) for k, v in params.items()}
        self.opt = torch.optim.Adam(
            [{"params": [p], "lr": float(lrs[k]), "name": k} for k, p in self.params.items()], lr=0.0, eps=ADAM_EPS
        )

    def __len__(self) -> int:
        return int(self.params["means"].shape[0])

    def __getitem__(self, name: str) -> torch.nn.Parameter:
        return self.params[name]

    @property
    def means(self) -> torch.Tensor:
        return self.params["means"]

    @property
    def scales(self) -> torch.Tensor:
        return torch.exp(self.params["log_scales"])

    @property
    def opacities(self) -> torch.Tensor:
        """(N,) in (0, 1)."""
        return torch.sigmoid(self.params["opacity"][:, 0])

    def _group(self, name: str) -> dict:
        return next(g for g in self.opt.param_groups if g["name"] == name)

    def set_lr(self, name: str, lr: float) -> None:
        self._group(name)["lr"] = float(lr)

    def freeze(self, names) -> None:
        """Stop optimising ``names`` (lr 0, no gradient)."""
        for n in names:
            self.set_lr(n, 0.0)
            self.params[n].requires_grad_(False)

    def add(self, name: str, value: torch.Tensor, lr: float) -> None:
        """A new per-Gaussian parameter (N, ...) in its own group."""
        assert value.shape[0] == len(self), (value.shape, len(self))
        p = torch.nn.Parameter(value.detach().clone().float())
        self.params[name] = p
        self.opt.add_param_group({"params": [p], "lr": float(lr), "name": name})

    def _swap(self, name: str, new: torch.Tensor, state_fn: Callable[[torch.Tensor], torch.Tensor] | None) -> None:
        group = self._group(name)
        old = group["params"][0]
        p = torch.nn.Parameter(new.detach().contiguous(), requires_grad=old.requires_grad)
        st = self.opt.state.pop(old, None)
        if st and state_fn is not None:
            self.opt.state[p] = {
                "step": st["step"],
                "exp_avg": state_fn(st["exp_avg"]),
                "exp_avg_sq": state_fn(st["exp_avg_sq"]),
            }
        group["params"][0] = p
        self.params[name] = p

    def extend(self, new: dict[str, torch.Tensor]) -> None:
        """Append Gaussians (every parameter given, (M, ...)); their Adam moments start at zero."""
        assert set(new) == set(self.params), (sorted(new), sorted(self.params))
        for k, v in new.items():
            old = self.params[k]
            self._swap(
                k,
                torch.cat([old.detach(), v.detach().to(old.dtype)]),
                lambda s, v=v: torch.cat([s, s.new_zeros((v.shape[0],) + s.shape[1:])]),
            )

    def keep(self, mask: torch.Tensor) -> None:
        """Keep the Gaussians where ``mask`` (N,) bool is set (with their Adam moments)."""
        assert mask.shape == (len(self),), mask.shape
        for k in list(self.params):
            self._swap(k, self.params[k].detach()[mask], lambda s: s[mask])

    def replace(self, name: str, value: torch.Tensor) -> None:
        """Replace one parameter's values (its Adam moments restart at zero), e.g. the opacity reset."""
        self._swap(name, value, lambda s: torch.zeros_like(s))

    def state(self) -> dict[str, torch.Tensor]:
        return {k: v.detach().clone() for k, v in self.params.items()}


# -- rendering ------------------------------------------------------------------------------------------------------


@dataclass
class Screen:
    """What densification reads of one render: ``visible`` (V, N) bool, ``radii`` (V, N) screen radii in pixels,
    and after ``backward`` the view-space positional gradient (:meth:`ndc_grad_norm`)."""

    visible: torch.Tensor
    radii: torch.Tensor
    width: int
    height: int
    mean2d: torch.Tensor | None = None  # (V, N, 2), gradient retained (torch backend)
    means: torch.Tensor | None = None  # the 3D means parameter (gsplat backend)
    c2w: torch.Tensor | None = None
    intr: torch.Tensor | None = None

    def ndc_grad_norm(self) -> torch.Tensor:
        """(V, N): |dL/d mean2d| in NDC units (pixels x (W/2, H/2)), as 3DGS's densification statistic."""
        scale = torch.tensor([0.5 * self.width, 0.5 * self.height], device=self.visible.device)
        if self.mean2d is not None:
            g = self.mean2d.grad
            if g is None:
                return torch.zeros(self.visible.shape, device=self.visible.device)
            return (g.detach() * scale.to(g)).norm(dim=-1)
        g3 = self.means.grad
        if g3 is None:
            return torch.zeros(self.visible.shape, device=self.visible.device)
        w2c = torch.linalg.inv(self.c2w)
        g_cam = torch.einsum("vij,nj->vni", w2c[:, :3, :3], g3.detach())
        z = (torch.einsum("vij,nj->vni", w2c[:, :3, :3], self.means.detach()) + w2c[:, None, :3, 3])[..., 2]
        px = torch.stack([g_cam[..., 0] * z / self.intr[:, None, 0], g_cam[..., 1] * z / self.intr[:, None, 1]], -1)
        return (px * scale.to(px)).norm(dim=-1)


def render(
    gs: GaussianSet,
    features: torch.Tensor,
    c2w: torch.Tensor,
    intr: torch.Tensor,
    height: int,
    width: int,
    raster: RasterConfig,
    track: bool = False,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, Screen | None]:
    """Rasterize ``gs`` with ``features`` (N, C) or (V, N, C) into cameras c2w (V, 4, 4), intr (V, 4).

    Returns features (V, H, W, C) premultiplied, alpha (V, H, W, 1), depth (V, H, W, 1) (alpha-weighted z, as
    :func:`frng.render.rasterize`), and with ``track`` the :class:`Screen` densification reads."""
    quats, scales, op = gs["quats"], gs.scales, gs.opacities
    kw = raster.kwargs()
    backend = resolve_backend(kw.pop("backend"), gs.means.device)
    if backend not in TILE_KERNELS:
        out = rasterize(gs.means, quats, scales, op, features, c2w, intr, height, width, backend=backend, **kw)
        if not track:
            return (*out, None)
        with torch.no_grad():
            proj = project_gaussians(
                gs.means, quats, scales, c2w, intr, height, width, near=kw["near"], eps2d=kw["eps2d"]
            )
        screen = Screen(proj.valid, proj.extent.max(-1).values, width, height, means=gs.means, c2w=c2w, intr=intr)
        return (*out, screen)
    proj = project_gaussians(
        gs.means,
        quats,
        scales,
        c2w,
        intr,
        height,
        width,
        near=kw["near"],
        eps2d=kw["eps2d"],
        max_radius_px=kw["max_radius_px"],
        opacities=op,
    )
    if track and proj.mean2d.requires_grad:
        proj.mean2d.retain_grad()
    feats, alpha, depth = rasterize_tiles(
        proj,
        op,
        features,
        height,
        width,
        tile=kw["tile_size"],
        chunk=kw["chunk"],
        min_transmittance=kw["min_transmittance"],
        compile=kw["compile"],
        kernel=backend,
    )
    screen = None
    if track:
        screen = Screen(proj.valid, proj.extent.detach().max(-1).values, width, height, mean2d=proj.mean2d)
    return feats, alpha, depth, screen


# -- densification --------------------------------------------------------------------------------------------------


def quat_rotate(quats: torch.Tensor, v: torch.Tensor) -> torch.Tensor:
    """Rotate v (N, 3) by quaternions (N, 4) (w, x, y, z), any norm."""
    from frng.render.project import quat_to_rotmat

    return (quat_to_rotmat(quats) @ v[..., None])[..., 0]


@dataclass
class Densifier:
    """3DGS's adaptive density control over a stage of ``steps`` steps (module docstring). ``extent``: the
    cameras' extent (:meth:`TrainViews.extent`); ``width``: the image width; ``max_gaussians``: no densification
    beyond it (None: no cap).

    The screen-size prune: 3DGS drops Gaussians whose 3-sigma radius exceeds 20 px of an ~800 px image (2.5 %); at
    64-128 px that is under 3 px, the size a budget-capped fit's Gaussians need, so here it is 10 % of the width."""

    steps: int
    start: int
    until: int
    every: int
    reset_every: int
    grad_threshold: float
    extent: float
    width: int
    max_gaussians: int | None
    generator: torch.Generator
    grad_accum: torch.Tensor = field(default=None)
    denom: torch.Tensor = field(default=None)
    max_radii: torch.Tensor = field(default=None)
    resets: int = 0

    def _reset_stats(self, n: int, device: torch.device) -> None:
        self.grad_accum, self.denom, self.max_radii = (torch.zeros(n, device=device) for _ in range(3))

    def record(self, gs: GaussianSet, screen: Screen) -> None:
        """Accumulate one step's statistics (after ``backward``)."""
        if self.grad_accum is None or self.grad_accum.shape[0] != len(gs):
            self._reset_stats(len(gs), gs.means.device)
        g = screen.ndc_grad_norm()
        vis = screen.visible
        self.grad_accum += (g * vis).sum(0)
        self.denom += vis.float().sum(0)
        r = torch.where(vis, screen.radii, torch.zeros_like(screen.radii)).max(0).values
        self.max_radii = torch.maximum(self.max_radii, r)

    @torch.no_grad()
    def step(self, gs: GaussianSet, step: int) -> None:
        """After the optimiser's step ``step`` (1-based): densify / prune / reset when the schedule says so."""
        if step >= self.until:
            return
        if step > self.start and step % self.every == 0 and self.grad_accum is not None:
            self._densify_and_prune(gs, step)
        if step % self.reset_every == 0:
            op = torch.minimum(gs.opacities, torch.full_like(gs.opacities, RESET_OPACITY))
            gs.replace("opacity", inverse_sigmoid(op)[:, None])
            self.resets += 1

    def _densify_and_prune(self, gs: GaussianSet, step: int) -> None:
        grads = self.grad_accum / self.denom.clamp_min(1.0)
        big = gs.scales.max(-1).values > PERCENT_DENSE * self.extent
        sel = grads >= self.grad_threshold
        room = None if self.max_gaussians is None else max(0, int(self.max_gaussians) - len(gs))
        if room is not None and int(sel.sum()) > room:  # keep the largest gradients that fit
            order = torch.argsort(torch.where(sel, grads, torch.full_like(grads, -1.0)), descending=True)
            sel = torch.zeros_like(sel)
            sel[order[:room]] = True
        clone, split = sel & ~big, sel & big
        params = gs.state()
        new = {k: v[clone] for k, v in params.items()}  # clones: copies in place (3DGS densify_and_clone)
        if bool(split.any()):  # splits: SPLIT_N samples from the Gaussian, scales / (0.8 N)
            rep = {k: v[split].repeat((SPLIT_N,) + (1,) * (v.ndim - 1)) for k, v in params.items()}
            std = torch.exp(rep["log_scales"])
            sample = torch.randn(std.shape, generator=self.generator).to(std.device) * std
            rep["means"] = rep["means"] + quat_rotate(rep["quats"], sample)
            rep["log_scales"] = torch.log(std / (0.8 * SPLIT_N))
            new = {k: torch.cat([new[k], rep[k]]) for k in new}
        n_before = len(gs)
        gs.extend(new)
        n_new = len(gs) - n_before
        # prune: the split originals, transparent ones, and (after the first reset) the huge ones
        drop = torch.cat([split, split.new_zeros(n_new)])
        drop |= gs.opacities < MIN_OPACITY
        if self.resets > 0:
            radii = torch.cat([self.max_radii, self.max_radii.new_zeros(n_new)])
            drop |= radii > MAX_SCREEN_FRACTION * self.width
            drop |= gs.scales.max(-1).values > MAX_WORLD_FRACTION * self.extent
        if bool(drop.all()):
            drop[0] = False
        gs.keep(~drop)
        self._reset_stats(len(gs), gs.means.device)


# -- the loop -------------------------------------------------------------------------------------------------------

StepFn = Callable[[GaussianSet, torch.Tensor, int], tuple[torch.Tensor, torch.Tensor, "Screen | None"]]
"""One step's forward: (gs, view indices (B,), step) -> (loss, predicted rgb (B, H, W, 3), Screen or None)."""


@dataclass
class Curve:
    """The loss / PSNR of every step (the PSNR of the step's batch against its ground truth)."""

    rows: list[tuple[int, float, float]] = field(default_factory=list)
    seconds: float = 0.0

    def csv(self) -> str:
        return "step,loss,psnr\n" + "".join(f"{s},{l:.6g},{p:.4f}\n" for s, l, p in self.rows)

    def mean_loss(self, first: bool, fraction: float = 0.1) -> float:
        """Mean loss over the first (or last) ``fraction`` of the steps."""
        k = max(1, int(len(self.rows) * fraction))
        part = self.rows[:k] if first else self.rows[-k:]
        return float(np.mean([r[1] for r in part]))


def optimise(
    gs: GaussianSet,
    views: TrainViews,
    steps: int,
    step_fn: StepFn,
    generator: torch.Generator,
    views_per_step: int = 1,
    densifier: Densifier | None = None,
    schedule: Callable[[GaussianSet, int], None] | None = None,
    label: str = "fit",
    curve: Curve | None = None,
    step_offset: int = 0,
    log_every: int = 50,
) -> Curve:
    """Run ``steps`` Adam steps of ``step_fn`` over ``views`` (module docstring). ``schedule(gs, step)`` runs before
    each step (learning rates, SH degree); ``densifier`` after it. Progress on stderr every ``log_every`` steps.
    Appends to ``curve`` (steps numbered from ``step_offset + 1``) and returns it."""
    curve = curve or Curve()
    stack: list[int] = []
    B = max(1, min(int(views_per_step), len(views)))
    t0 = time.perf_counter()
    for i in range(1, int(steps) + 1):
        step = step_offset + i
        if schedule is not None:
            schedule(gs, i)
        idx = []
        while len(idx) < B:
            if not stack:
                stack = torch.randperm(len(views), generator=generator).tolist()
            idx.append(stack.pop())
        idx_t = torch.tensor(idx, device=views.rgb.device)
        gs.opt.zero_grad(set_to_none=True)
        loss, pred, screen = step_fn(gs, idx_t, i)
        if not torch.isfinite(loss):
            raise FloatingPointError(f"{label}: loss is {float(loss)} at step {step}")
        loss.backward()
        if densifier is not None and screen is not None:
            densifier.record(gs, screen)
        gs.opt.step()
        if densifier is not None:
            densifier.step(gs, i)
        p = psnr(pred, views.rgb[idx_t])
        curve.rows.append((step, float(loss.detach()), p))
        if i % log_every == 0 or i == steps:
            el = time.perf_counter() - t0
            print(
                f"[{label}] step {i}/{steps} loss {float(loss.detach()):.4f} psnr {p:.2f} gaussians {len(gs)} "
                f"({i / el:.1f} steps/s)",
                file=sys.stderr,
                flush=True,
            )
    curve.seconds += time.perf_counter() - t0
    return curve


def exp_lr(step: int, steps: int, init: float, final: float) -> float:
    """3DGS's ``get_expon_lr_func`` (no delay): log-linear from ``init`` to ``final`` over ``steps``."""
    t = min(max(step / max(steps, 1), 0.0), 1.0)
    return math.exp((1 - t) * math.log(init) + t * math.log(final))


def knn_scale(points: torch.Tensor, k: int = 3, chunk: int = 2048) -> torch.Tensor:
    """(N,) 3DGS's initial scale: sqrt of the mean squared distance to the ``k`` nearest other points."""
    assert points.ndim == 2 and points.shape[1] == 3, points.shape
    out = []
    for s in range(0, points.shape[0], chunk):
        d = torch.cdist(points[s : s + chunk], points)
        d2 = d.topk(min(k + 1, points.shape[0]), largest=False).values[:, 1:] ** 2
        out.append(d2.mean(-1).clamp_min(1e-8).sqrt())
    return torch.cat(out)
