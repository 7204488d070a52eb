"""Stage ``frng eval-backbone``: quality of the frozen priors on held-out (test) objects, beside trivial baselines.

Backbone (``{results}/metrics/backbone.csv``, one row per image, columns ``task, method, object, light, view,
psnr, ssim``), metrics from :func:`frng.metrics.evaluate_pair` with the ``aligned`` protocol (per-channel
least-squares scale, foreground PSNR/SSIM, white background, sRGB-encoded):

- ``nvs``: reconstruction from the 6 rig views under the object's input light, one DDIM pass under that light,
  rendered at the held-out extra input views (``in_06 ..``, same light, never fed to the model);
- ``relight``: the same geometry, one DDIM pass per held-out target light, rendered at the target views;
- baseline ``mean-image``: the per-pixel mean of all TRAINING objects' target images (RGBA), the same for every
  view -- what a model that ignores its input would output at best under L2.

IDM (``{results}/metrics/idm.csv``, one row per object and method): on each test object's input views
(foreground of the G-buffer), ``normal_deg`` (mean angular error), ``albedo_psnr`` (linear albedo, foreground),
``roughness_mae``, ``metallic_mae``, ``depth_mae``; baseline ``constant``: the training split's foreground mean
albedo/roughness/metallic/depth, and normals facing the camera.

A summary (means per task/method) is printed.
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path

import numpy as np
import torch

from frng import config as frng_config
from frng.priors import build_idm, load_backbone
from frng import training as tr
from frng.priors.data import PriorObject
from frng.priors.intrinsics import IntrinsicPriors


def _rgba(rgb: torch.Tensor, alpha: torch.Tensor) -> np.ndarray:
    return torch.cat([rgb, alpha], -1).detach().cpu().numpy().astype(np.float32)


def _score(pred: np.ndarray, gt: np.ndarray) -> dict:
    from frng.metrics import evaluate_pair

    m = evaluate_pair(pred, gt, protocol="aligned")
    return {"psnr": m["psnr"], "ssim": m["ssim"]}


def mean_image(train_objects: list[PriorObject]) -> np.ndarray:
    imgs = [torch.cat([v.rgb, v.alpha], -1) for o in train_objects for v in o.targets.values()]
    return torch.cat(imgs).mean(0).numpy()


def eval_backbone(config: dict, model, test: list[PriorObject], mean_img: np.ndarray, device="cpu") -> list[dict]:
    rows = []
    nd = model.cfg.den_views
    for obj in test:
        light_in = obj.input_lights[0]
        views = obj.inputs[light_in]
        rig = views.select(range(obj.rig_views))
        rest = list(range(obj.rig_views, len(views)))
        jobs = []
        if rest:
            jobs.append(("nvs", light_in, views.select(rest)))
        jobs += [("relight", l, obj.targets[l]) for l in obj.target_lights]
        rgb, a, c2w, intr = (x.to(device) for x in (rig.rgb, rig.alpha, rig.c2w, rig.intr))
        H, W = rgb.shape[1:3]
        t_geo, _, gauss, keep = model.reconstruct(rgb, a, c2w, intr)
        for i, (task, light, out) in enumerate(jobs):
            g = torch.Generator(device=device).manual_seed(config["seed"] + i)
            env = obj.envs[light].to(device)[None]
            sh, _ = model.denoise(t_geo, gauss, keep, env, c2w[:nd], intr[:nd], H, W, generator=g)
            pred, pa, _ = model.render(gauss, sh, out.c2w.to(device), out.intr.to(device), H, W, keep)
            pred = pred.clamp(0, 1) ** 2.2
            for k, name in enumerate(out.names):
                gt = _rgba(out.rgb[k], out.alpha[k])
                base = {"task": task, "object": obj.id, "light": light, "view": name}
                rows.append(base | {"method": "backbone"} | _score(_rgba(pred[k], pa[k]), gt))
                rows.append(base | {"method": "mean-image"} | _score(mean_img, gt))
    return rows


def idm_scores(pred: IntrinsicPriors, gt: IntrinsicPriors) -> dict:
    fg = gt.mask[..., 0] > 0.5
    n = float(fg.sum())
    if n == 0:
        raise ValueError("IDM evaluation: the G-buffers have no foreground pixel")
    cos = (pred.normal * gt.normal).sum(-1).clamp(-1, 1)
    ang = torch.rad2deg(torch.acos(cos))[fg].mean()
    mse = ((pred.albedo - gt.albedo) ** 2)[fg].mean()
    return {
        "normal_deg": float(ang),
        "albedo_psnr": float(10 * math.log10(1.0 / max(float(mse), 1e-10))),
        "roughness_mae": float((pred.roughness - gt.roughness).abs()[fg].mean()),
        "metallic_mae": float((pred.metallic - gt.metallic).abs()[fg].mean()),
        "depth_mae": float((pred.depth - gt.depth).abs()[fg].mean()),
    }


def constant_priors(train_objects: list[PriorObject], views, gt: IntrinsicPriors) -> IntrinsicPriors:
    """The trivial baseline: training-split foreground means; normals facing the camera (-optical axis)."""
    sums: dict[str, torch.Tensor] = {}
    for o in train_objects:
        fg = o.gbuffer.mask[..., 0] > 0.5
        for k in ("albedo", "roughness", "metallic", "depth"):
            sums.setdefault(k, []).append(getattr(o.gbuffer, k)[fg])
    mean = {k: torch.cat(v).mean(0) for k, v in sums.items()}
    V, H, W = gt.mask.shape[:3]
    facing = -views.c2w[:, None, None, :3, 2].expand(V, H, W, 3)
    return IntrinsicPriors(normal=facing.clone(), depth=mean["depth"].expand(V, H, W, 1).clone(),
                           albedo=mean["albedo"].expand(V, H, W, 3).clone(),
                           roughness=mean["roughness"].expand(V, H, W, 1).clone(),
                           metallic=mean["metallic"].expand(V, H, W, 1).clone(), mask=gt.mask)


def eval_idm(config: dict, idm, test: list[PriorObject], train_objects: list[PriorObject]) -> list[dict]:
    rows = []
    for obj in test:
        views = obj.inputs[obj.input_lights[0]]
        pred = idm.priors(obj.id, views, obj.gbuffer)
        rows.append({"object": obj.id, "method": f"idm-{idm.kind}"} | idm_scores(pred, obj.gbuffer))
        rows.append({"object": obj.id, "method": "constant"} |
                    idm_scores(constant_priors(train_objects, views, obj.gbuffer), obj.gbuffer))
    return rows


def configure(parser: argparse.ArgumentParser) -> None:
    frng_config.add_config_argument(parser)
    parser.add_argument("--model", help="backbone model (default {results}/backbone/model.pt)")
    parser.add_argument("--backbone-csv", help="default {results}/metrics/backbone.csv")
    parser.add_argument("--idm-csv", help="default {results}/metrics/idm.csv")


def run(args: argparse.Namespace) -> int:
    import pandas as pd

    from frng import io
    from frng.priors.dataset import load_split

    config = frng_config.load(args.config)
    res = Path(config["results"])
    device = tr.resolve_device(config["device"])
    train_objs = load_split(config, "train")
    test = load_split(config, "test")
    model = load_backbone(Path(args.model or res / "backbone" / "model.pt"), device)
    bb = pd.DataFrame(eval_backbone(config, model, test, mean_image(train_objs), device))
    idm = pd.DataFrame(eval_idm(config, build_idm(config, device), test, train_objs))
    for df, path in ((bb, args.backbone_csv or res / "metrics" / "backbone.csv"),
                     (idm, args.idm_csv or res / "metrics" / "idm.csv")):
        with io.atomic_path(path) as tmp:
            df.to_csv(tmp, index=False, float_format="%.5g")
    print(bb.groupby(["task", "method"])[["psnr", "ssim"]].mean().round(3).to_string())
    print(idm.groupby("method")[["normal_deg", "albedo_psnr", "roughness_mae", "metallic_mae", "depth_mae"]]
          .mean().round(3).to_string())
    return 0
