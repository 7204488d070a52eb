"""Intrinsic decomposition models (IDMs): per-pixel normal, depth, albedo, roughness, metallic per input view.

Three kinds, chosen by ``idm.kind`` and produced through :func:`frng.priors.build_idm` (the registry):

- ``learned`` (default) -- :class:`LearnedIDM`, a small transformer over ALL input views at once (one token
  sequence, so attention runs across views: the multi-view analogue of feeding DiffusionRenderer a video), on
  top of explicit multi-view geometry cues. A few hundred training objects are far too few to learn multi-view
  stereo from scratch, so geometry comes from the soft visual hull of the known masks and cameras
  (:func:`frng.priors.multiview.geometry_cues`, computed per object without gradients: they are data) and the
  network predicts residuals on top of it.

  Per view and pixel: cues = [hull distance (normalised over [near, far]), hull normal (camera frame), photo
  agreement, hull hit] (6 channels, ``cues: true``). Tokenizer input: [diffusion-space RGB (3), alpha (1),
  Pluecker rays (6), cues (6)] -> 8x8 patches -> tokens; Pre-LN transformer (frng.nn); a linear patch
  detokenizer to ``pixel_features`` per pixel. The pixel head (keeps sub-patch detail) takes
  [pixel_features, RGB, alpha, cues] per pixel, plus (``head_global``) the object context: the alpha-weighted
  mean and standard deviation of those inputs and of the local contrast over ALL views of the object
  (:meth:`LearnedIDM.object_context`), standardised with running statistics of the training objects
  (:class:`RunningNorm`) -- roughness and metallic are properties of the object (diffuse / specular / fur), and
  without this context the head learnt no better than a constant. Then ``head_layers`` convolutions of
  ``head_hidden`` channels with ``head_kernel`` x ``head_kernel`` kernels (1 = a per-pixel MLP; 3 = 3x3 convs) and
  GELU, then 1x1 output layers (the geometry one initialised to ZERO) -> 9 raw values per pixel:

  ====== ======= ==========================================================================================
  raw    pass    decoding (hull: the cues; ``cos`` = ray direction . optical axis, z_hull = distance * cos)
  ====== ======= ==========================================================================================
  0:3    normal  normalise(hull normal + raw), CAMERA frame (OpenCV), rotated to world with the view's c2w
  3      depth   clamp(z_hull + tanh(raw) * depth_range, near, far)   (camera z)
  4:7    albedo  sigmoid
  7      rough.  sigmoid
  8      metal.  sigmoid
  ====== ======= ==========================================================================================

  So an untrained model (zero geometry output layer) outputs the visual hull's depth and normals;
  training learns corrections. With ``cues: false`` the model is the cue-free ablation: normal =
  normalise(raw), depth = near + sigmoid(raw) * (far - near), and the cues are neither computed nor fed.

  Trained on the training split's G-buffers (``frng idm-train``; the material outputs and the head's hidden
  layers at ``idm.train.head_lr`` x the learning rate), masked to the foreground:
  ``(1 - cos(n, n*)) + |depth_n - depth_n*| + |albedo - albedo*| + |rough - rough*| + |metal - metal*|`` (or, with
  ``idm.train.metallic_loss: bce``, the metallic logit's binary cross-entropy: :func:`idm_loss`)
  with depth normalised to [0, 1] over [near, far]. Then frozen.
- ``oracle`` -- the rendered G-buffers themselves (analysis / upper bound): :func:`oracle_priors`.
- ``diffusion-renderer`` -- DiffusionRenderer inverse-rendering output files: :mod:`frng.priors.diffusion_renderer`.

Every kind returns :class:`frng.priors.intrinsics.IntrinsicPriors` (shapes and conventions documented there).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, fields

import torch
import torch.nn.functional as F
from torch import nn

from frng import camera
from frng.nn import PatchDetokenizer, PatchTokenizer, Transformer
from frng.plan.sections import key, section
from frng.priors.diffusion import to_diffusion_space
from frng.priors.intrinsics import IntrinsicPriors
from frng.priors.multiview import CUE_CHANNELS, geometry_cues

RAW_CHANNELS = 9


@dataclass(frozen=True)
class IDMArch:
    """The learned IDM's architecture keys of the config's ``idm`` section (each key declared on its field), shared by
    the section (:class:`IDMSection`) and a model's architecture record (:class:`IDMConfig`)."""

    width: int = key(
        128,
        "learned IDM: width of the transformer over all input views jointly",
        type="integer",
        minimum=8,
        maximum=8192,
    )
    heads: int = key(
        4,
        "learned IDM: attention heads",
        type="integer",
        minimum=1,
        maximum=128,
    )
    depth: int = key(
        3,
        "learned IDM: transformer layers",
        type="integer",
        minimum=1,
        maximum=256,
    )
    pixel_features: int = key(
        16,
        "learned IDM: features the transformer hands to the per-pixel head",
        type="integer",
        minimum=1,
        maximum=4096,
    )
    cues: bool = key(
        True,
        "learned IDM on the visual hull of the input masks (`frng/priors/multiview.py`): hull cues (distance, normal, "
        "photo agreement, hit) into the tokenizer and the pixel head; depth = hull camera z + `tanh(raw) * "
        "depth_range`, normal = normalise(hull normal + raw) (a zero-initialised geometry output = the hull); false = "
        "no cues",
        type="boolean",
    )
    cue_bins: int = key(
        48,
        "samples per ray of the hull sweep (cost ~ bins x V^2 per object: ~2.5 s for 10 views at 64 px on one CPU "
        "thread)",
        type="integer",
        minimum=4,
        maximum=4096,
    )
    depth_range: float = key(
        0.5,
        "bound of the learned camera-z residual on the hull depth (world units)",
        type="number",
        exclusiveMinimum=0,
    )
    head_hidden: int = key(
        64,
        "channels of the pixel head's `head_layers` convolutions",
        type="integer",
        minimum=1,
        maximum=8192,
    )
    head_layers: int = key(
        2,
        "hidden layers (convolutions) of the pixel head, then 1x1 output layers (geometry residuals zero-initialised, "
        "material logits at PyTorch init)",
        type="integer",
        minimum=0,
        maximum=64,
    )
    head_kernel: int = key(
        1,
        "kernel of the pixel head's convolutions: 1 (per-pixel MLP) or 3 (3x3; ~3x slower training on a CPU)",
        type="integer",
        enum=[1, 3, 5],
    )
    head_global: bool = key(
        True,
        "the pixel head also sees the object context: mean and std over all views' foreground of its inputs and the "
        "local contrast, standardised by running training statistics (roughness / metallic are per-object properties)",
        type="boolean",
    )


@dataclass(frozen=True)
class IDMConfig(IDMArch):
    """Architecture of a learned IDM model (``model.pt``'s ``config``): the section's architecture keys plus
    ``patch`` (``model.patch_size``) and ``near``/``far`` (``backbone.near``/``far``)."""

    patch: int
    near: float
    far: float

    @classmethod
    def from_dict(cls, d: dict) -> IDMConfig:
        """Strict (:func:`frng.plan.sections.section`): unknown keys are errors, missing architecture keys take the
        schema's defaults; ``patch``, ``near`` and ``far`` must be given."""
        return section(cls, d, "idm")

    def to_dict(self) -> dict:
        return asdict(self)


@dataclass(frozen=True)
class IDMSection(IDMArch):
    """The config's ``idm`` section as inference reads it: which IDM (``kind``), the learned one's architecture and
    the DiffusionRenderer adapter's settings. The config holds :class:`frng.training.idm.IDMTrainingSection`, which
    adds the training (``idm.train``)."""

    kind: str = key(
        "learned",
        "`learned` (trained, frozen), `oracle` (the rendered G-buffers), `diffusion-renderer` (reads its PNGs)",
        type="string",
    )
    diffusion_renderer_dir: str | None = key(
        None,
        "`diffusion-renderer`: folder with one sub-folder per object of `<chunk>.<frame>.<pass>.png`",
        type=["string", "null"],
    )
    normal_space: str = key(
        "camera-opengl",
        "frame of DiffusionRenderer's normal PNGs",
        type="string",
        enum=["camera-opengl", "world"],
    )
    depth_invert: bool = key(
        False,
        "DiffusionRenderer depth PNG is bright = near",
        type="boolean",
    )


def idm_config(idm: IDMSection, patch_size: int, near: float, far: float) -> IDMConfig:
    """The learned IDM's architecture of the config's ``idm`` section with the patch size (``model.patch_size``) and
    near/far (the backbone's)."""
    arch = {f.name: getattr(idm, f.name) for f in fields(IDMArch)}
    return IDMConfig(**arch, patch=patch_size, near=near, far=far)


class PixelHead(nn.Module):
    """``layers`` k x k convolutions + GELU, then two 1x1 output layers, ``out_geo`` (the first ``geo`` channels:
    normal and depth residuals; initialised to ZERO) and ``out_mat`` (the rest: material logits; PyTorch's init --
    zero there learnt albedo more slowly on the smoke tier), so the trainer can give them different learning rates:
    (N, H, W, C) -> (N, H, W, out). With k = 1 it is a per-pixel MLP."""

    def __init__(self, in_channels: int, hidden: int, out_channels: int, layers: int, kernel: int, geo: int = 4):
        super().__init__()
        mods: list[nn.Module] = []
        c = in_channels
        for _ in range(layers):
            mods += [nn.Conv2d(c, hidden, kernel, padding=kernel // 2, padding_mode="replicate"), nn.GELU()]
            c = hidden
        self.body = nn.Sequential(*mods)
        self.out_geo = nn.Conv2d(c, geo, 1)
        self.out_mat = nn.Conv2d(c, out_channels - geo, 1)
        nn.init.zeros_(self.out_geo.weight)  # step 0 = the hull's depth and normals
        nn.init.zeros_(self.out_geo.bias)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        h = self.body(x.permute(0, 3, 1, 2))
        return torch.cat([self.out_geo(h), self.out_mat(h)], dim=1).permute(0, 2, 3, 1)


class RunningNorm(nn.Module):
    """Standardises object-level vectors (B, C) with running statistics over the training objects (buffers, saved
    with the model): in training mode each call first updates them (cumulative average over the first
    ``1 / momentum`` calls, then an exponential moving average), in eval mode they are fixed. Batch size 1 (one
    object per step) is fine, unlike BatchNorm."""

    def __init__(self, dim: int, momentum: float = 0.02, eps: float = 1e-3):
        super().__init__()
        self.momentum, self.eps = momentum, eps
        self.register_buffer("mean", torch.zeros(dim))
        self.register_buffer("var", torch.ones(dim))
        self.register_buffer("count", torch.zeros(()))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        if self.training:
            with torch.no_grad():
                for row in x.detach().float():
                    self.count += 1
                    m = max(1.0 / float(self.count), self.momentum)
                    delta = row - self.mean
                    self.mean += m * delta
                    self.var.copy_((1 - m) * (self.var + m * delta**2) if self.count > 1 else 0.0 * self.var)
        if self.count < 2:  # no spread measured yet (e.g. an untrained model): identity
            return x
        return (x - self.mean) * self.var.clamp_min(self.eps).rsqrt()


class LearnedIDM(nn.Module):
    """Multi-view IDM. See the module docstring."""

    def __init__(self, cfg: IDMConfig):
        super().__init__()
        self.cfg = cfg
        D, p = cfg.width, cfg.patch
        nc = CUE_CHANNELS if cfg.cues else 0
        self.tokenizer = PatchTokenizer(3 + 1 + 6 + nc, D, p)
        self.view_embed = nn.Parameter(torch.zeros(D))
        self.transformer = Transformer(D, cfg.depth, cfg.heads)
        self.detokenizer = PatchDetokenizer(D, cfg.pixel_features, p)
        head_in = cfg.pixel_features + 4 + nc
        ctx = 2 * (head_in + 1)  # object context (see object_context)
        self.context_norm = RunningNorm(ctx) if cfg.head_global else None
        head_in += ctx if cfg.head_global else 0
        self.pixel_head = PixelHead(head_in, cfg.head_hidden, RAW_CHANNELS, cfg.head_layers, cfg.head_kernel)

    @staticmethod
    def object_context(x: torch.Tensor, rgb: torch.Tensor, alpha: torch.Tensor) -> torch.Tensor:
        """Object-level appearance statistics for every pixel (material class is a property of the object):
        x (B, V, H, W, C) per-pixel head inputs, rgb (B, V, H, W, 3) diffusion space, alpha (B, V, H, W, 1).
        Appends the local contrast |lum - 3x3 mean of lum| (lum = mean RGB; specular highlights and fur are
        high-frequency) to x, then takes the alpha-weighted mean and standard deviation over ALL views and pixels:
        returns (B, 2 (C + 1)) (standardised by ``context_norm`` and given to every pixel of the object)."""
        B, V, H, W, _ = x.shape
        lum = rgb.mean(-1).reshape(B * V, 1, H, W)
        contrast = (lum - F.avg_pool2d(lum, 3, 1, 1, count_include_pad=False)).abs().reshape(B, V, H, W, 1)
        q = torch.cat([x, contrast], dim=-1)
        wsum = alpha.sum((1, 2, 3)).clamp_min(1.0)  # (B, 1)
        mean = (q * alpha).sum((1, 2, 3)) / wsum  # (B, C + 1)
        var = ((q - mean[:, None, None, None]) ** 2 * alpha).sum((1, 2, 3)) / wsum
        return torch.cat([mean, (var + 1e-6).sqrt()], dim=-1)

    @torch.no_grad()
    def cues(self, images: torch.Tensor, alpha: torch.Tensor, c2w: torch.Tensor, intr: torch.Tensor) -> dict:
        """Geometry cues of a batch of objects (no gradients; the inputs are data): images (B, V, H, W, 3), alpha
        (B, V, H, W, 1), c2w (B, V, 4, 4), intr (B, V, 4) -> dict of float32 (B, V, H, W, C): ``features``
        (CUE_CHANNELS, see :func:`frng.priors.multiview.geometry_cues`), ``distance`` (1) hull distance along
        the unit ray, ``z`` (1) hull camera z (= distance * ray . optical axis), ``normal`` (3) hull normal,
        camera frame."""
        c = self.cfg
        out: dict[str, list] = {"features": [], "distance": [], "z": [], "normal": []}
        H, W = images.shape[2:4]
        with torch.autocast(device_type=images.device.type, enabled=False):
            for b in range(images.shape[0]):
                cb, ib = c2w[b].float(), intr[b].float()
                g = geometry_cues(images[b].float(), alpha[b].float(), cb, ib, c.near, c.far, bins=c.cue_bins)
                _, d = camera.pixel_rays(cb, ib, H, W)
                cos = (d * cb[:, None, None, :3, 2]).sum(-1, keepdim=True)  # ray . optical axis
                out["features"].append(g["features"])
                out["distance"].append(g["distance"])
                out["z"].append(g["distance"] * cos)
                out["normal"].append(g["normal"])
        return {k: torch.stack(v) for k, v in out.items()}

    def forward(
        self, images: torch.Tensor, alpha: torch.Tensor, c2w: torch.Tensor, intr: torch.Tensor, cues: dict | None = None
    ) -> torch.Tensor:
        """images (B, V, H, W, 3) linear premultiplied RGB; alpha (B, V, H, W, 1); c2w (B, V, 4, 4);
        intr (B, V, 4); cues: :meth:`cues` of these inputs when already computed (the trainer caches them),
        else computed here (``cues: true``). Returns raw predictions (B, V, H, W, 9), float32: [camera-frame
        normal vector (not yet unit, 3), camera z (1, not yet clamped), albedo/roughness/metallic logits (5)];
        :meth:`decode` finishes them."""
        B, V, H, W, _ = images.shape
        c = self.cfg
        with torch.autocast(device_type=images.device.type, enabled=False):  # ray geometry in fp32
            o, d = camera.pixel_rays(c2w.reshape(B * V, 4, 4).float(), intr.reshape(B * V, 4).float(), H, W)
            rays = camera.plucker(o, d).reshape(B, V, H, W, 6)
        rgb = to_diffusion_space(images)
        a = 2.0 * alpha - 1.0
        inp = [rgb, a, rays]
        if c.cues:
            if cues is None:
                cues = self.cues(images, alpha, c2w, intr)
            cf = 2.0 * cues["features"] - 1.0
            inp.append(cf)
        tok = self.tokenizer(torch.cat(inp, dim=-1))  # (B, V, h, w, D)
        _, _, h, w, D = tok.shape
        x = self.transformer(tok.reshape(B, V * h * w, D)).reshape(B, V, h, w, D)
        feat = self.detokenizer(x)  # (B, V, H, W, F)
        with torch.autocast(device_type=images.device.type, enabled=False):  # small per-pixel head: fp32
            head_in = [feat.float(), rgb.float(), a.float()] + ([cf.float()] if c.cues else [])
            if c.head_global:
                g = self.context_norm(self.object_context(torch.cat(head_in, dim=-1), rgb.float(), alpha.float()))
                head_in.append(g[:, None, None, None].expand(B, V, H, W, -1))
            r = self.pixel_head(torch.cat(head_in, dim=-1).reshape(B * V, H, W, -1)).reshape(B, V, H, W, -1)
            if c.cues:
                n = cues["normal"] + r[..., 0:3]
                z = cues["z"] + torch.tanh(r[..., 3:4]) * c.depth_range
            else:
                n = r[..., 0:3]
                z = c.near + torch.sigmoid(r[..., 3:4]) * (c.far - c.near)
            return torch.cat([n, z, r[..., 4:]], dim=-1)

    def decode(self, raw: torch.Tensor, alpha: torch.Tensor, c2w: torch.Tensor) -> dict[str, torch.Tensor]:
        """raw (B, V, H, W, 9) from :meth:`forward` -> dict of passes (B, V, H, W, C) in world space (not yet
        masked)."""
        c = self.cfg
        n_cam = F.normalize(raw[..., 0:3].float(), dim=-1, eps=1e-6)
        R = c2w[:, :, None, None, :3, :3].float()  # (B, V, 1, 1, 3, 3)
        normal = (R @ n_cam.unsqueeze(-1)).squeeze(-1)
        return {
            "normal": normal,
            "depth": raw[..., 3:4].float().clamp(c.near, c.far),
            "albedo": torch.sigmoid(raw[..., 4:7].float()),
            "roughness": torch.sigmoid(raw[..., 7:8].float()),
            "metallic": torch.sigmoid(raw[..., 8:9].float()),
            "mask": alpha,
        }

    @torch.no_grad()
    def predict(
        self, images: torch.Tensor, alpha: torch.Tensor, c2w: torch.Tensor, intr: torch.Tensor
    ) -> IntrinsicPriors:
        """One object's views: images (V, H, W, 3), alpha (V, H, W, 1), c2w (V, 4, 4), intr (V, 4)."""
        raw = self(images[None], alpha[None], c2w[None], intr[None])
        out = self.decode(raw, alpha[None], c2w[None])
        return IntrinsicPriors(**{k: v[0].float() for k, v in out.items()}).masked()


METALLIC_LOSSES = ("l1", "bce")


def idm_loss(
    model: LearnedIDM, raw: torch.Tensor, alpha: torch.Tensor, c2w: torch.Tensor, target: dict, metallic: str = "l1"
) -> dict:
    """Masked per-pass losses. raw (B, V, H, W, 9) from :meth:`LearnedIDM.forward`; target: dict of G-buffer passes
    (B, V, H, W, C) in the IntrinsicPriors conventions.

    metallic (``idm.train.metallic_loss``): ``l1`` = |sigmoid(raw) - metallic*| like the other passes, or ``bce`` =
    binary cross-entropy of the metallic logit against metallic*. Metallic is nearly binary per object (0 or ~0.8-1)
    and most objects are not metal: L1's minimiser is the median, so a head that cannot yet tell metal from paint
    settles at 0 and stays there (measured: every object, training metals included, predicted ~0.001); BCE's is the
    probability of metal, which keeps the signal the head needs to learn it.

    Returns a dict of scalar tensors (``normal``, ``depth``, ``albedo``, ``roughness``, ``metallic``, ``total``).
    The mask is the G-buffer coverage (``target['mask']`` > 0.5)."""
    if metallic not in METALLIC_LOSSES:
        raise ValueError(f"idm.train.metallic_loss must be one of {METALLIC_LOSSES}, got {metallic!r}")
    pred = model.decode(raw, alpha, c2w)
    fg = (target["mask"] > 0.5).float()
    denom = fg.sum().clamp_min(1.0)
    c = model.cfg

    def l1(a, b):
        return ((a - b).abs().mean(-1, keepdim=True) * fg).sum() / denom

    losses = {
        "normal": ((1.0 - (pred["normal"] * target["normal"]).sum(-1, keepdim=True)) * fg).sum() / denom,
        "depth": l1((pred["depth"] - c.near) / (c.far - c.near), (target["depth"] - c.near) / (c.far - c.near)),
        "albedo": l1(pred["albedo"], target["albedo"]),
        "roughness": l1(pred["roughness"], target["roughness"]),
    }
    if metallic == "bce":
        bce = F.binary_cross_entropy_with_logits(raw[..., 8:9].float(), target["metallic"].float(), reduction="none")
        losses["metallic"] = (bce * fg).sum() / denom
    else:
        losses["metallic"] = l1(pred["metallic"], target["metallic"])
    losses["total"] = sum(losses.values())
    return losses


def build(cfg: dict | IDMConfig) -> LearnedIDM:
    if isinstance(cfg, dict):
        cfg = IDMConfig.from_dict(cfg)
    return LearnedIDM(cfg)
