"""Stage ``frng idm-train``: train the learned IDM on the training split's G-buffers, then freeze it.

One step = one training object, one of its input lights, its input views (the 6 rig views with probability 1/2,
else a random subset of 2..all input views, so every V in 2..10 is seen) processed jointly; loss
:func:`frng.priors.idm.idm_loss` against the views' G-buffers. Only training objects are read.

Outputs in ``--out`` (default ``{results}/idm``): ``model.pt``, ``checkpoint.pt`` (resume), ``loss.csv``,
``loss.png``, ``train.json``.
"""

from __future__ import annotations

import argparse
import random
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import torch
from tqdm import tqdm

from frng import config as frng_config
from frng import io
from frng.priors import idm as idm_mod
from frng import training as tr
from frng.priors.backbone_train import sample_views
from frng.priors.data import PriorObject


@dataclass
class IDMTrainConfig:
    steps: int = 400
    lr: float = 1e-3
    warmup: int = 30
    bf16: bool = True
    checkpoint_every: int = 50

    @classmethod
    def from_dict(cls, d: dict) -> "IDMTrainConfig":
        return cls(**{k: v for k, v in d.items() if k in cls.__dataclass_fields__})


def idm_config(config: dict) -> idm_mod.IDMConfig:
    d = {k: v for k, v in config["idm"].items() if k in idm_mod.IDMConfig.__dataclass_fields__}
    d["patch"] = config["model"]["patch_size"]
    d["near"], d["far"] = config["backbone"]["near"], config["backbone"]["far"]
    return idm_mod.IDMConfig.from_dict(d)


LOSS_NAMES = ["total", "normal", "depth", "albedo", "roughness", "metallic"]


def train(config: dict, objects: list[PriorObject], out: Path, steps: int | None = None,
          stop_after: int | None = None) -> Path:
    """Train (or resume) the learned IDM; returns the model path (or the checkpoint when stopped early)."""
    if any(o.split != "train" for o in objects):
        raise ValueError("idm-train must only see training objects")
    if not objects:
        raise ValueError("idm-train: no training objects")
    tcfg = IDMTrainConfig.from_dict(config["idm"].get("train", {}))
    total = steps or tcfg.steps
    cfg = idm_config(config)
    device = tr.resolve_device(config.get("device", "auto"))
    tr.seed_everything(config["seed"] + 1)
    model = idm_mod.LearnedIDM(cfg).to(device)
    opt = torch.optim.AdamW(model.parameters(), lr=tcfg.lr, weight_decay=0.01)
    fingerprint = {"arch": cfg.to_dict(), "train": asdict(tcfg), "steps": total, "seed": config["seed"],
                   "objects": sorted(o.id for o in objects)}
    out.mkdir(parents=True, exist_ok=True)
    ckpt = tr.Checkpointer(out, tcfg.checkpoint_every)
    state = ckpt.load(model, opt, fingerprint)
    start = state["step"] if state else 0
    rng = random.Random(config["seed"] + 1)
    if state:
        rng.setstate(state["sample_rng"])
    log = tr.LossLog(out, LOSS_NAMES)
    log.truncate(start)
    timer = tr.Timer(state["elapsed"] if state else 0.0)
    model.train()
    bar = tqdm(range(start, total), initial=start, total=total, desc="idm", dynamic_ncols=True)
    ran = 0
    for step in bar:
        for g in opt.param_groups:
            g["lr"] = tr.cosine_lr(step, total, tcfg.lr, tcfg.warmup)
        obj = objects[rng.randrange(len(objects))]
        light, idx = sample_views(obj, rng)
        v = obj.inputs[light].select(idx)
        gb = obj.gbuffer.select(torch.as_tensor(idx)).to(device)
        c2w, intr = v.c2w.to(device)[None], v.intr.to(device)[None]
        alpha = v.alpha.to(device)[None]
        with tr.autocast(device, tcfg.bf16):
            raw = model(v.rgb.to(device)[None], alpha, c2w, intr)
        target = {k: t[None] for k, t in gb.as_dict().items()}
        losses = idm_mod.idm_loss(model, raw.float(), alpha, c2w, target)
        opt.zero_grad(set_to_none=True)
        losses["total"].backward()
        torch.nn.utils.clip_grad_norm_(model.parameters(), 1.0)
        opt.step()
        vals = {k: float(x.detach()) for k, x in losses.items()}
        log.append(step + 1, timer.elapsed(), vals)
        bar.set_postfix(loss=f"{vals['total']:.4f}")
        ran += 1
        extra = lambda: {"sample_rng": rng.getstate(), "elapsed": timer.elapsed()}  # noqa: E731
        if ckpt.due(step + 1, total):
            ckpt.save(step + 1, model, opt, fingerprint, extra())
            log.plot("IDM training loss")
        if stop_after is not None and ran >= stop_after and step + 1 < total:
            ckpt.save(step + 1, model, opt, fingerprint, extra())
            return out / "checkpoint.pt"
    bar.close()
    log.plot("IDM training loss")
    path = out / "model.pt"
    tr.save_torch({"kind": "learned", "config": cfg.to_dict(), "state_dict": model.state_dict(), "steps": total},
                  path)
    io.write_json(out / "train.json", {"steps": total, "wall_s": round(timer.elapsed(), 1), "device": str(device),
                                       "objects": len(objects), "bf16": tcfg.bf16,
                                       "parameters": sum(p.numel() for p in model.parameters())})
    return path


def configure(parser: argparse.ArgumentParser) -> None:
    frng_config.add_config_argument(parser)
    parser.add_argument("--out", help="output folder (default {results}/idm)")
    parser.add_argument("--steps", type=int, help="override idm.train.steps")


def run(args: argparse.Namespace) -> int:
    from frng.priors.dataset import load_split

    config = frng_config.load(args.config)
    out = Path(args.out or Path(config["results"], "idm"))
    t0 = time.time()
    objects = load_split(config, "train", with_targets=False)
    print(f"idm-train: {len(objects)} training objects loaded in {time.time() - t0:.1f}s")
    print(f"idm-train: wrote {train(config, objects, out, steps=args.steps)}")
    return 0
