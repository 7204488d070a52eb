"""Train the learned IDM on the training split's G-buffers, then freeze it (stage :mod:`frng.stages.idm_train`,
``frng idm-train``).

One step = one training object, one of its input lights, its input views (ALL of them -- what the IDM sees at
inference, ``frng idm-priors`` / ``relight`` -- with probability ``all_views``, else a random subset of 2..all input
views, so every V in 2..10 is seen) processed jointly; loss :func:`frng.priors.idm.idm_loss` against the views'
G-buffers. Only training objects are read.

The geometry cues (:func:`frng.priors.multiview.geometry_cues`, the visual hull: most of a step's cost on a CPU) are
data, so :class:`CueCache` keeps those of the all-views samples in memory: the hull depends only on the masks and
cameras, identical under every input light, so it is computed once per object; only the light-dependent photo
agreement channel is recomputed per (object, light). Random subsets are computed per step.

The loop is :func:`frng.training.loop.fit` (resume, schedule, clipping at ``grad_clip`` with no update on a non-finite
gradient norm, checkpoints). Outputs in ``--out`` (default ``{results}/idm``): ``model.pt``, ``checkpoint.pt``
(resume), ``loss.csv``, ``loss.png``, ``train.json``.
"""

from __future__ import annotations

import random
from dataclasses import dataclass
from pathlib import Path

import torch

from frng import camera, checkpoint, io
from frng.device import autocast, resolve_device
from frng.hashing import data_digest
from frng.plan.sections import FINITE, key, register
from frng.priors import idm as idm_mod
from frng.priors import multiview
from frng.priors.dataset import PriorObject, Views
from frng.seeding import seed_everything
from frng.training import loop as tr


@register("idm.train")
@dataclass(frozen=True)
class IDMTrainConfig:
    """The config's ``idm.train`` section (each key declared on its field) plus two internal fields."""

    steps: int = key(
        400,
        "learned IDM training steps",
        type="integer",
        minimum=1,
        maximum=10000000,
    )
    lr: float = key(
        0.001,
        "learned IDM training: AdamW's peak learning rate",
        type="number",
        exclusiveMinimum=0,
        maximum=10,
        **FINITE,
    )
    warmup: int = key(
        30,
        "learned IDM training: steps of the linear learning-rate warm-up",
        type="integer",
        minimum=0,
        maximum=10000000,
    )
    bf16: bool = key(
        True,
        "learned IDM training: bf16 autocast",
        type="boolean",
    )
    checkpoint_every: int = key(
        50,
        "learned IDM training: resumable checkpoint period (steps)",
        type="integer",
        minimum=1,
        maximum=10000000,
    )
    all_views: float = key(
        0.75,
        "probability of a training step on all input views (as at inference), else a random subset of 2..all; the "
        "all-views hull cues are cached in memory per object",
        type="number",
        minimum=0,
        maximum=1,
    )
    head_lr: float = key(
        10.0,
        "learning-rate multiplier of the pixel head's hidden layers and material output (the transformer keeps `lr`)",
        type="number",
        exclusiveMinimum=0,
    )
    geo_lr: float = key(
        0.3,
        "learning-rate multiplier of the pixel head's geometry-residual output layer (0 = keep the hull's depth and "
        "normals)",
        type="number",
        minimum=0,
    )
    metallic_loss: str = key(
        "bce",
        "the metallic pass's loss (`frng.priors.idm.idm_loss`): `l1` like the other passes, or `bce` (binary "
        "cross-entropy of the metallic logit). Metallic is nearly binary per object and most objects are not metal, "
        "so L1's minimiser (the median) is 0: with `l1` the default tier's IDM predicted metallic ~0.001 on every "
        "object, its 25 training metals included; with `bce` (scratch, 2026-11-30) 0.57 on the training metals, 0.94 "
        "on the test metal, 0.03 on the rest, and the roughness error fell (test MAE 0.194 -> 0.171). F-RNG (full) "
        "trained on those priors: +0.03 / -0.03 dB on two seeds (noise), the mirror-metal test object unchanged: its "
        "decoder does not yet turn the metal prior into reflections. The default since the reproduction of "
        "2026-11-30, with `frng.specular_start` (which reads the metal prior)",
        type="string",
        enum=["l1", "bce"],
    )
    # internal, not config keys: the values the IDM has always trained with
    weight_decay: float = 0.01
    grad_clip: float = 1.0


@register("idm")
@dataclass(frozen=True)
class IDMTrainingSection(idm_mod.IDMSection):
    """The config's whole ``idm`` section: what inference reads (:class:`frng.priors.idm.IDMSection`) and the training
    (``idm.train``; :class:`IDMTrainConfig`)."""

    CONFIG_DOC = "the intrinsic decomposition model (frng/priors/idm.py)"

    train: IDMTrainConfig = key({})


def sample_views(obj: PriorObject, rng: random.Random, all_views: float) -> tuple[str, list[int]]:
    """Input light and input view indices of one training sample (see the module docstring)."""
    light = rng.choice(obj.input_lights)
    n = len(obj.inputs[light])
    if rng.random() < all_views or n <= 2:
        return light, list(range(n))
    k = rng.randint(2, n)
    return light, sorted(rng.sample(range(n), k))


class CueCache:
    """In-memory geometry cues (:meth:`frng.priors.idm.LearnedIDM.cues`) of the all-views training samples.

    ``get(model, obj, light, idx, views)`` -> cue dict with a batch dimension of 1 (tensors on ``views``'
    device). Only full view sets (``idx`` = all input views) are stored: the hull once per object (reused under
    another light when its masks and cameras are the same), the photo agreement per (object, light)."""

    def __init__(self):
        self.hull: dict[str, tuple[torch.Tensor, torch.Tensor, dict]] = {}  # oid -> (alpha, c2w, cues)
        self.per_light: dict[tuple[str, str], dict] = {}

    def get(self, model: idm_mod.LearnedIDM, obj: PriorObject, light: str, idx: list[int], views: Views) -> dict:
        def compute() -> dict:
            return model.cues(views.rgb[None], views.alpha[None], views.c2w[None], views.intr[None])

        if len(idx) != len(obj.inputs[light]):
            return compute()
        key = (obj.id, light)
        if key in self.per_light:
            return self.per_light[key]
        base = self.hull.get(obj.id)
        if base is None or not (torch.equal(base[0], views.alpha) and torch.equal(base[1], views.c2w)):
            cues = compute()
            self.hull.setdefault(obj.id, (views.alpha, views.c2w, cues))
        else:  # same masks and cameras -> same hull; only the photo agreement depends on the light's colours
            cues = {k: v.clone() for k, v in base[2].items()}
            H, W = views.rgb.shape[1:3]
            o, d = camera.pixel_rays(views.c2w.float(), views.intr.float(), H, W)
            dist = cues["distance"][0, ..., 0]
            pts = o + d * dist[..., None]
            agree = multiview.photo_agreement(
                views.rgb.float(), views.alpha.float(), pts, views.c2w.float(), views.intr.float(), dist
            )
            cues["features"][0, ..., 4:5] = agree * cues["features"][0, ..., 5:6]  # [dist, normal, agree, hit]
        self.per_light[key] = cues
        return cues


def param_groups(model: idm_mod.LearnedIDM, tcfg: IDMTrainConfig) -> list[dict]:
    """Optimiser groups with an ``lr_mult``: the pixel head's hidden layers and material output layer at
    ``head_lr`` x lr (a small MLP that starts at zero output), its geometry-residual output layer at ``geo_lr`` x lr,
    everything else (the transformer) at lr."""
    head = [p for n, p in model.pixel_head.named_parameters() if not n.startswith("out_geo.")]
    geo = list(model.pixel_head.out_geo.parameters())
    ids = {id(p) for p in head + geo}
    rest = [p for p in model.parameters() if id(p) not in ids]
    return [
        {"params": rest, "lr_mult": 1.0},
        {"params": head, "lr_mult": tcfg.head_lr},
        {"params": geo, "lr_mult": tcfg.geo_lr},
    ]


LOSS_NAMES = ["total", "normal", "depth", "albedo", "roughness", "metallic"]


def train(
    idm: IDMTrainingSection,
    patch_size: int,
    near: float,
    far: float,
    device: str,
    seed: int,
    objects: list[PriorObject],
    out: Path,
    steps: int | None = None,
    stop_after: int | None = None,
) -> Path:
    """Train (or resume, :func:`frng.training.loop.fit`) the learned IDM; returns the model path (or the checkpoint
    when stopped early). ``idm``: the config's ``idm`` section; ``patch_size``: ``model.patch_size``; ``near``,
    ``far``: ``backbone.near``/``far``; ``device``: the config's; ``seed``: the models' seed (``train_seed``, else
    ``seed``; the IDM trains with ``seed + 1``)."""
    tr.check_training_split(objects, "idm-train")
    tcfg = idm.train
    total = steps or tcfg.steps
    cfg = idm_mod.idm_config(idm, patch_size, near, far)
    device = resolve_device(device)
    seed_everything(seed + 1, device)
    model = idm_mod.LearnedIDM(cfg).to(device)
    opt = torch.optim.AdamW(param_groups(model, tcfg), lr=tcfg.lr, weight_decay=tcfg.weight_decay)
    fingerprint = checkpoint.fingerprint(
        cfg.to_dict(),
        tcfg,
        total,
        seed,
        objects=sorted(o.id for o in objects),
        data=data_digest(objects),
    )
    rng = random.Random(seed + 1)
    cue_cache = CueCache()  # data only: a resumed run recomputes the same cues (bit-identical, see the test)

    def step_fn(step: int) -> dict[str, float]:
        obj = objects[rng.randrange(len(objects))]
        light, idx = sample_views(obj, rng, tcfg.all_views)
        v = obj.inputs[light].select(idx)
        gb = obj.gbuffer.select(torch.as_tensor(idx)).to(device)
        c2w, intr = v.c2w.to(device)[None], v.intr.to(device)[None]
        alpha = v.alpha.to(device)[None]
        vd = Views(v.names, v.rgb.to(device), v.alpha.to(device), v.c2w.to(device), v.intr.to(device))
        cues = cue_cache.get(model, obj, light, idx, vd) if cfg.cues else None
        with autocast(device, tcfg.bf16):
            raw = model(vd.rgb[None], alpha, c2w, intr, cues=cues)
        target = {k: t[None] for k, t in gb.as_dict().items()}
        losses = idm_mod.idm_loss(model, raw.float(), alpha, c2w, target, tcfg.metallic_loss)
        losses["total"].backward()
        return {k: float(x.detach()) for k, x in losses.items()}

    def save_model(path: Path) -> None:
        io.save_torch(
            {"kind": "learned", "config": cfg.to_dict(), "state_dict": model.state_dict(), "steps": total}, path
        )

    trainer = tr.Trainer(
        model=model,
        optimizer=opt,
        step=step_fn,
        save_model=save_model,
        summary=lambda run: tr.run_summary(run, device, objects, tcfg.bf16, model),
        loss_names=LOSS_NAMES,
        title="IDM training loss",
        desc="idm",
        rngs={"sample": rng},
        device=device,
    )
    return tr.fit(trainer, tcfg, out=out, total=total, fingerprint=fingerprint, stop_after=stop_after)
