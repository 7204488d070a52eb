"""Train the RelitLRM-style backbone on the training split, then freeze it (stage :mod:`frng.stages.backbone_train`,
``frng backbone-train``).

One step = one training object (``backbone.train.batch`` objects accumulated):

1. input light A (random input light) and input views: with probability 1/2 the 6 rig views, else a random
   subset of 2..all input views (rig + extras), so that any V in 2..10 works at inference;
2. target light B, uniformly over the object's target lights and input lights (B = A is the reconstruction case);
   its available views are the target views (target light) or all input views (input light);
3. geometry: T_geo, raw params -> per-pixel Gaussians (input pixels with alpha >= 0.5 are rendered);
4. diffusion: t ~ U{0..999}; the clean images of B at ``den_views`` random views of B (the denoising cameras),
   gamma-encoded to [-1, 1], noised to x_t; light tokens of B's env map, zeroed with probability ``cond_drop``;
   one DiT pass -> T_app -> SH;
5. x0-prediction through rendering: render at the denoising views plus up to 2 more views of B (supervision
   views) and compare with the clean images in gamma space:
   ``L = |rgb - rgb*|^2 + lambda_alpha |a - a*|^2 + lambda_per * LPIPS-vgg(rgb, rgb*) [after perceptual_after
   steps] + lambda_depth * depth``, where ``depth`` is the foreground L1 between each input pixel's Gaussian
   distance along its ray and the G-buffer's (normalised by far - near): a training aid from the training
   split's G-buffers only; ``+ lambda_opacity * opacity``, the mean L1 between each foreground pixel's Gaussian's
   opacity and its input alpha: a pixel-aligned Gaussian covers what its pixel covers. Without it the backbone
   learns semi-transparent Gaussians (median opacity ~0.3 on the default tier's data), whose blend of front and
   back layers lowers the L2 of the per-pixel render but shows at inference as ghosted, washed-out objects.

With ``cue_noise`` > 0 (off by default) the multi-view cues the geometry transformer reads
(:meth:`frng.priors.backbone.RelitLRMBackbone.prior_raw`) are perturbed with Gaussian noise in training
(``cue_noise`` x :data:`CUE_NOISE_SIGMA` per cue channel; the prior's raw 9-vector and the light cue's normals are
left as they are): inference computes them the same way from its inputs, so the noise only teaches the network not
to lean on their exact values (:func:`perturbed_cues`).

Nothing from test objects or test lights is read: objects come from the training split, lights from those
objects' own (training-pool) lights.

Outputs in ``--out`` (default ``{results}/backbone``): ``model.pt`` (frozen weights + config + sha256 recorded by
caches), ``checkpoint.pt`` (resume), ``loss.csv``, ``loss.png``, ``train.json`` (steps, wall time, device).
The loop is :func:`frng.training.loop.fit`: rerunning the command after an interruption resumes from the last
checkpoint when the config and data are unchanged; after a finished run it trains again.
"""

from __future__ import annotations

import random
from dataclasses import dataclass
from pathlib import Path

import torch
import torch.nn.functional as F

from frng import checkpoint, io
from frng.device import autocast, bf16_ok, resolve_device
from frng.hashing import data_digest
from frng.memo import TensorMemo
from frng.plan.sections import FINITE, key, register
from frng.priors import backbone as bb
from frng.priors.backbone_config import BackboneSection, backbone_config
from frng.priors.dataset import PriorObject, Views
from frng.priors.diffusion import to_diffusion_space
from frng.seeding import seed_everything
from frng.training import loop as tr


@register("backbone.train")
@dataclass(frozen=True)
class BackboneTrainConfig:
    """The config's ``backbone.train`` section (each key declared on its field)."""

    steps: int = key(
        600,
        "training steps of the backbone",
        type="integer",
        minimum=1,
        maximum=10000000,
    )
    batch: int = key(
        1,
        "objects per step",
        type="integer",
        minimum=1,
        maximum=1024,
    )
    lr: float = key(
        0.0004,
        "AdamW's peak learning rate: cosine decay after a linear warm-up",
        type="number",
        exclusiveMinimum=0,
        maximum=10,
        **FINITE,
    )
    warmup: int = key(
        50,
        "steps of the linear learning-rate warm-up",
        type="integer",
        minimum=0,
        maximum=10000000,
    )
    weight_decay: float = key(
        0.05,
        "AdamW's weight decay",
        type="number",
        minimum=0,
    )
    grad_clip: float = key(
        1.0,
        "gradient-norm clip",
        type="number",
        exclusiveMinimum=0,
    )
    lambda_alpha: float = key(
        1.0,
        "weight of the alpha-mask L2",
        type="number",
        minimum=0,
    )
    lambda_depth: float = key(
        0.5,
        "weight of the G-buffer ray-distance L1 (a training aid)",
        type="number",
        minimum=0,
    )
    lambda_opacity: float = key(
        0.5,
        "mean L1 between each foreground pixel's Gaussian's opacity and its input alpha (a pixel-aligned Gaussian "
        "covers what its pixel covers); 0 = opacities free, which the backbone drives to ~0.3 (ghosted, washed-out "
        "renders at inference)",
        type="number",
        minimum=0,
    )
    lambda_per: float = key(
        0.5,
        "weight of the LPIPS loss",
        type="number",
        minimum=0,
    )
    perceptual_after: int = key(
        200,
        "the perceptual loss is switched on after this many steps",
        type="integer",
        minimum=0,
        maximum=10000000,
    )
    perceptual_net: str = key(
        "vgg",
        "LPIPS backbone of the perceptual loss",
        type="string",
        enum=["vgg", "alex"],
    )
    supervision_views: int = key(
        2,
        "extra views of the target light rendered for the loss beside the denoising views",
        type="integer",
        minimum=0,
        maximum=64,
    )
    inference_geometry: bool = key(
        False,
        "the loss renders what inference renders: the per-pixel Gaussians as their pixels' surfels "
        "(`backbone.surfels`) less the layers the frontal view selection drops (`backbone.view_select`), normals "
        "taken without gradient; false = the learned shapes of every foreground pixel (the backbone then learns "
        "near-point Gaussians that inference replaces). Measured on the 4839079 reproduction's data (docs/results.md, "
        "docs/studies/, scratch): 1.7x faster steps (fewer Gaussians rendered), backbone relighting -0.17 [-0.25, "
        "-0.09] dB (as large as a second training seed's -0.17), F-RNG on its caches -0.03 [-0.09, +0.03]; 10 views "
        "still below 8. Not the default",
        type="boolean",
    )
    cue_noise: float = key(
        0.0,
        "scale of the Gaussian noise added in training to the multi-view cues the geometry transformer reads "
        "(`frng.training.backbone.CUE_NOISE_SIGMA`: 0.01 on the normalised hull distance, 0.1 on each hull-normal "
        "component and on photo agreement, none on the hit flag; the prior's Gaussians and the light cue are not "
        "perturbed); 0 = none. At 1, scratch runs gave F-RNG +0.08 / +0.10 dB on two backbone seeds, but the "
        "fresh-clone reproduction of f2a4ab1 only +0.01 [-0.03, +0.05] and the Cook-Torrance ablation -1.34: off by "
        "default (docs/priors.md)",
        type="number",
        minimum=0,
    )
    bf16: bool = key(
        True,
        "bf16 autocast of the transformers",
        type="boolean",
    )
    checkpoint_every: int = key(
        50,
        "resumable checkpoint period (steps)",
        type="integer",
        minimum=1,
        maximum=10000000,
    )


def _gamma(rgb: torch.Tensor) -> torch.Tensor:
    return (to_diffusion_space(rgb) + 1.0) / 2.0


@register("backbone")
@dataclass(frozen=True)
class BackboneTrainingSection(BackboneSection):
    """The config's whole ``backbone`` section: what inference reads (:class:`frng.priors.backbone_config.BackboneSection`)
    and the training (``backbone.train``; :class:`BackboneTrainConfig`)."""

    CONFIG_DOC = "the frozen RelitLRM-style backbone (frng/priors/backbone.py)"

    train: BackboneTrainConfig = key({})


def sample_views(obj: PriorObject, rng: random.Random) -> tuple[str, list[int]]:
    """Input light and input view indices of one training sample (see the module docstring)."""
    light = rng.choice(obj.input_lights)
    n = len(obj.inputs[light])
    if rng.random() < 0.5 or n <= 2:
        return light, list(range(min(obj.rig_views, n)))
    k = rng.randint(2, n)
    return light, sorted(rng.sample(range(n), k))


class CueCache(TensorMemo):
    """The multi-view cues (:meth:`frng.priors.backbone.RelitLRMBackbone.prior_raw`) of each object's rig views
    under each input light, keyed (object id, input light), kept from their first use for the rest of the run.

    Half the training samples take exactly the rig views (:func:`sample_views`), and the cues are a fixed function
    of those views' images, masks and cameras: the plane sweep behind them (V^2 H W K bilinear reads) took 0.39-0.41
    s of a 0.95 s step on the default tier's data at 96 px on one CPU thread (synthetic: ``frng bench cues``); the
    rig views' cues of 122 objects x 2 input lights are ~1 GB at 96 px. Other view subsets (random, rarely
    repeated) are computed every time. README "Performance (training)"."""


# standard deviation of the training noise on each multi-view cue channel (frng.priors.multiview.CUE_CHANNELS: hull
# distance normalised to [0, 1], the hull normal's 3 camera-frame components, photo agreement, hull hit), at
# ``backbone.train.cue_noise`` 1. Why (docs/priors.md): until 0714da8 the training step computed the cues under its
# bf16 autocast (inference in fp32), and that accidental noise made F-RNG 0.15 dB better on the backbone's caches
# than fp32 cues did; this noise at 1 gave +0.08 / +0.10 of it back in scratch runs (two backbone seeds) but +0.01
# in a full reproduction, so it is off by default (docs/priors.md).
CUE_NOISE_SIGMA = (0.01, 0.1, 0.1, 0.1, 0.1, 0.0)


def perturbed_cues(
    cues: tuple[torch.Tensor, torch.Tensor, torch.Tensor], scale: float, generator: torch.Generator
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """What :meth:`frng.priors.backbone.RelitLRMBackbone.prior_raw` returned, (features (B, V, H, W, C), raw,
    normals), with N(0, (scale CUE_NOISE_SIGMA)^2) added to the features' channels (new tensors: the cue cache's
    stay as they are); raw and normals unchanged. ``generator`` on the features' device."""
    feats, raw, normals = cues
    assert feats.shape[-1] == len(CUE_NOISE_SIGMA), (feats.shape, CUE_NOISE_SIGMA)
    sigma = torch.tensor(CUE_NOISE_SIGMA, device=feats.device, dtype=feats.dtype) * scale
    noise = torch.randn(feats.shape, generator=generator, device=feats.device, dtype=feats.dtype)
    return feats + noise * sigma, raw, normals


def step_loss(
    model: bb.RelitLRMBackbone,
    obj: PriorObject,
    tcfg: BackboneTrainConfig,
    step: int,
    rng: random.Random,
    device: torch.device,
    perceptual=None,
    cues: CueCache | None = None,
) -> dict[str, torch.Tensor]:
    """Losses of one training sample (see the module docstring); ``cues``: where the rig views' multi-view cues are
    kept between steps (None: computed every step)."""
    cfg = model.cfg
    light_a, idx = sample_views(obj, rng)
    inp = obj.inputs[light_a].select(idx)
    choices = [("t", l) for l in obj.target_lights] + [("i", l) for l in obj.input_lights]
    kind, light_b = rng.choice(choices)
    avail: Views = obj.targets[light_b] if kind == "t" else obj.inputs[light_b]
    order = list(range(len(avail)))
    rng.shuffle(order)
    n_den = min(cfg.den_views, len(avail))
    den = avail.select(order[:n_den])
    sup = avail.select(order[: n_den + tcfg.supervision_views])

    rgb_in, a_in = inp.rgb.to(device), inp.alpha.to(device)
    c2w_in, intr_in = inp.c2w.to(device), inp.intr.to(device)
    H, W = rgb_in.shape[1:3]
    with autocast(device, tcfg.bf16):
        kept = None

        def compute_cues():
            return model.prior_raw(rgb_in[None], a_in[None], c2w_in[None], intr_in[None])

        if cues is not None and cfg.cues and idx == list(range(min(obj.rig_views, len(obj.inputs[light_a])))):
            kept = cues.get((obj.id, light_a), compute_cues)
        if cfg.cues and tcfg.cue_noise > 0:
            kept = compute_cues() if kept is None else kept
            gen = torch.Generator(device=kept[0].device).manual_seed(rng.randrange(2**31))
            kept = perturbed_cues(kept, tcfg.cue_noise, gen)
        t_geo, raw, _, normals = model.encode_geometry(rgb_in[None], a_in[None], c2w_in[None], intr_in[None], kept)
    raw = raw[0].float()
    pixels = model.pixel_inputs(rgb_in, a_in, normals[0] if cfg.light_cue else None, obj.envs[light_a].to(device))
    gauss = model.gaussians(raw, c2w_in, intr_in)
    keep = a_in.reshape(-1) >= 0.5
    if tcfg.inference_geometry:  # render what inference renders: surfels, one layer per surface
        gauss, keep = model.inference_geometry(gauss, keep, c2w_in, intr_in)

    t = torch.randint(0, model.schedule.steps, (1,), device=device)
    x0 = to_diffusion_space(den.rgb.to(device))[None]
    x_t = model.schedule.q_sample(x0, t, torch.randn_like(x0))
    env = None if rng.random() < cfg.cond_drop else obj.envs[light_b].to(device)[None]
    with autocast(device, tcfg.bf16):
        t_app = model.appearance_tokens(t_geo, env, x_t, den.c2w.to(device)[None], den.intr.to(device)[None], t)
        sh = model.sh_coefficients(t_app, pixels, env)[0].float()
    rgb, alpha, _ = model.render(gauss, sh, sup.c2w.to(device), sup.intr.to(device), H, W, keep)
    tgt = _gamma(sup.rgb.to(device))
    losses = {
        "l2": F.mse_loss(rgb, tgt),
        "alpha": F.mse_loss(alpha, sup.alpha.to(device)),
    }
    total = losses["l2"] + tcfg.lambda_alpha * losses["alpha"]
    if obj.gbuffer is not None and tcfg.lambda_depth > 0:
        gb = obj.gbuffer.select(torch.as_tensor(idx))
        fg = (gb.mask.to(device) > 0.5).float()
        dist_t = bb.ray_distance_target(gb.depth.to(device), c2w_in, intr_in)
        w = torch.sigmoid(raw[..., 0:1])
        dist_p = cfg.near * (1 - w) + cfg.far * w
        losses["depth"] = ((dist_p - dist_t).abs() * fg).sum() / fg.sum().clamp_min(1.0) / (cfg.far - cfg.near)
        total = total + tcfg.lambda_depth * losses["depth"]
    if tcfg.lambda_opacity > 0 and bool(keep.any()):  # a pixel's Gaussian covers what its pixel covers
        losses["opacity"] = (gauss.opacities[keep].float() - a_in.reshape(-1)[keep].float()).abs().mean()
        total = total + tcfg.lambda_opacity * losses["opacity"]
    if perceptual is not None and step >= tcfg.perceptual_after and tcfg.lambda_per > 0:
        p = rgb.clamp(0, 1).permute(0, 3, 1, 2)
        q = tgt.permute(0, 3, 1, 2)
        losses["perceptual"] = perceptual(p, q)
        total = total + tcfg.lambda_per * losses["perceptual"]
    losses["total"] = total
    return losses


LOSS_NAMES = ["total", "l2", "alpha", "depth", "opacity", "perceptual"]


def train(
    backbone: BackboneTrainingSection,
    patch_size: int,
    device: str,
    seed: int,
    objects: list[PriorObject],
    out: Path,
    steps: int | None = None,
    stop_after: int | None = None,
    cue_cache: bool = True,
) -> Path:
    """Train (or resume, :func:`frng.training.loop.fit`) the backbone on ``objects`` (training split only); returns the
    model path.

    ``stop_after``: stop (after checkpointing) once this many steps have run in this call -- for tests of
    resumption. ``cue_cache``: keep the rig views' multi-view cues between steps (:class:`CueCache`; the same
    weights either way, False only for the test that checks so). ``steps`` overrides ``backbone.train.steps``.
    ``backbone``: the config's ``backbone`` section; ``patch_size``, ``device``: its ``model.patch_size`` and
    ``device``; ``seed``: the models' seed (``train_seed``, else ``seed``)."""
    tr.check_training_split(objects, "backbone-train")
    tcfg = backbone.train
    total = steps or tcfg.steps
    cfg = backbone_config(backbone, patch_size)
    device = resolve_device(device)
    seed_everything(seed, device)
    model = bb.RelitLRMBackbone(cfg).to(device)
    opt = torch.optim.AdamW(model.parameters(), lr=tcfg.lr, betas=(0.9, 0.95), weight_decay=tcfg.weight_decay)
    fingerprint = checkpoint.fingerprint(
        cfg.to_dict(),
        tcfg,
        total,
        seed,
        objects=sorted(o.id for o in objects),
        data=data_digest(objects),
    )
    rng = random.Random(seed)
    perceptual = None
    if tcfg.lambda_per > 0 and tcfg.perceptual_after < total:
        from frng.perceptual import PerceptualLoss

        perceptual = PerceptualLoss(
            "lpips",
            net=tcfg.perceptual_net,
            srgb=False,
            autocast_bf16=tcfg.bf16 and device.type == "cpu" and bf16_ok(device),
        ).to(device)

    cues = CueCache() if cue_cache else None

    def step_fn(step: int) -> dict[str, float]:
        acc: dict[str, float] = {}
        for _ in range(tcfg.batch):
            obj = objects[rng.randrange(len(objects))]
            losses = step_loss(model, obj, tcfg, step, rng, device, perceptual, cues)
            (losses["total"] / tcfg.batch).backward()
            for k, v in losses.items():
                acc[k] = acc.get(k, 0.0) + float(v.detach()) / tcfg.batch
        return acc

    def save_model(path: Path) -> None:
        io.save_torch(
            {"kind": backbone.kind, "config": cfg.to_dict(), "state_dict": model.state_dict(), "steps": total},
            path,
        )

    trainer = tr.Trainer(
        model=model,
        optimizer=opt,
        step=step_fn,
        save_model=save_model,
        summary=lambda run: tr.run_summary(run, device, objects, tcfg.bf16, model),
        loss_names=LOSS_NAMES,
        title="backbone training loss",
        desc="backbone",
        postfix=("total", "l2"),
        rngs={"sample": rng},
        device=device,
    )
    return tr.fit(trainer, tcfg, out=out, total=total, fingerprint=fingerprint, stop_after=stop_after)
