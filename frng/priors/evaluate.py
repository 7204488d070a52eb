"""Quality of the frozen priors on held-out (test) objects, beside trivial baselines.

Backbone (``{results}/metrics/backbone.csv``, one row per image, columns ``task, method, object, light, view,
psnr, psnr_interior, silhouette_iou, ssim, lpips, depth_error``), metrics from :func:`frng.metrics.evaluate_pair` with the ``aligned`` protocol
(per-channel least-squares scale, foreground PSNR/SSIM, white background, sRGB-encoded):

- ``nvs``: reconstruction from the 6 rig views under the object's input light, one DDIM pass under that light,
  rendered at the held-out extra input views (``in_06 ..``, same light, never fed to the model);
- ``relight``: the same geometry, one DDIM pass per held-out target light, rendered at the target views;
- baseline ``mean-image``: the per-pixel mean of all TRAINING objects' target images (RGBA), the same for every
  view -- what a model that ignores its input would output at best under L2;
- quality-ladder references on the same images (:func:`oracle_colour_render`): ``gt-depth+oracle-colour`` --
  one Gaussian per input pixel of the 6 rig views at the G-buffer's depth (a surfel in the G-buffer normal's plane
  covering the pixel's footprint, :func:`gt_depth_gaussians`; opacity = input alpha), each coloured with the
  ground-truth image's colour where it projects: the per-pixel representation on the true surface;
  ``backbone-geometry+oracle-colour`` -- the backbone's own Gaussians coloured the same way: what its geometry alone
  allows. Oracle colouring rewards small Gaussians inside the silhouettes more than true depth (each splat
  resamples the target image where it lands), so the backbone's row can score above the ground-truth-depth row.

Every row also records the aligned protocol's per-channel scales (``scale_r, scale_g, scale_b``) and
``depth_error`` (:func:`depth_error`: the geometry's mean absolute distance error against the G-buffer at the rig's
input pixels, per object, world units): the backbone's for its own and its oracle-colour rows, 0 for the
ground-truth-depth row, NaN for the mean image.

IDM (``{results}/metrics/idm.csv``, one row per object and method): on each test object's input views
(foreground of the G-buffer), ``normal_deg`` (mean angular error), ``albedo_psnr`` (linear albedo, foreground),
``roughness_mae``, ``metallic_mae``, ``depth_mae``; baseline ``constant``: the training split's foreground mean
albedo/roughness/metallic/depth, and normals facing the camera.

The stage that writes both files and prints a summary (means per task/method): :mod:`frng.stages.eval_backbone`
(``frng eval-backbone``).
"""

from __future__ import annotations

import math

import numpy as np
import torch

from frng.priors.dataset import PriorObject
from frng.priors.intrinsics import IntrinsicPriors
from frng.priors.registry import view_priors
from frng.priors.surfels import PIXEL_STD


def _rgba(rgb: torch.Tensor, alpha: torch.Tensor) -> np.ndarray:
    return torch.cat([rgb, alpha], -1).detach().cpu().numpy().astype(np.float32)


def _score(pred: np.ndarray, gt: np.ndarray) -> dict:
    from frng.metrics import evaluate_pair

    m = evaluate_pair(pred, gt, protocol="aligned")
    return {
        k: m[k] for k in ("psnr", "psnr_interior", "silhouette_iou", "ssim", "lpips", "scale_r", "scale_g", "scale_b")
    }


def oracle_colour_render(
    gauss, keep: torch.Tensor, out, max_radius_px: float | None
) -> tuple[torch.Tensor, torch.Tensor]:
    """Render Gaussians at the views of ``out`` (a :class:`frng.priors.dataset.Views`), each Gaussian coloured with that
    view's ground truth (unpremultiplied linear colour, bilinear) where its mean projects -- an oracle appearance
    that isolates the geometry. gauss: N Gaussians; keep (N,) bool. Returns linear premultiplied RGB (Vo, H, W, 3)
    and alpha (Vo, H, W, 1)."""
    from frng import camera
    from frng.priors.multiview import sample_image
    from frng.render import rasterize

    g = gauss[keep]
    H, W = out.rgb.shape[1:3]
    col = out.rgb / out.alpha.clamp_min(1e-3) * (out.alpha > 1e-3)
    rgbs, alphas = [], []
    for k in range(len(out)):
        c2w, intr = out.c2w[k : k + 1], out.intr[k : k + 1]
        uv, _ = camera.project(g.means, c2w, intr)
        colours = sample_image(col[k : k + 1], uv)[0]
        rgb, a, _ = rasterize(
            g.means, g.quats, g.scales, g.opacities, colours, c2w, intr, H, W, max_radius_px=max_radius_px
        )
        rgbs.append(rgb)
        alphas.append(a)
    return torch.cat(rgbs), torch.cat(alphas)


def gt_depth_gaussians(rig, gbuffer, footprint_px: float, decode_cfg):
    """One Gaussian per rig pixel at the G-buffer's depth, and the keep mask (input alpha >= 0.5, G-buffer coverage
    and depth): the representation's reference for :func:`oracle_colour_render`.

    Each is a surfel on the true surface (:func:`frng.priors.surfels.surfel_shapes`, the shape the backbone's own
    Gaussians take at inference): a flat Gaussian in the plane of the G-buffer normal, ``footprint_px`` pixels wide
    at its distance across the tilt and up to 4x that along it. So the surface an input view sees at a grazing angle
    is covered without gaps from other views, which isotropic Gaussians of the pixel footprint are not (they leave
    the background showing through). Pixels without a G-buffer normal keep the isotropic Gaussian of
    :func:`frng.gaussians.isotropic_raw`."""
    from frng import camera
    from frng.gaussians import Gaussians, isotropic_raw, pixel_gaussians
    from frng.priors.backbone import ray_distance_target
    from frng.priors.surfels import surfel_shapes

    V, H, W = rig.alpha.shape[:3]
    dist = ray_distance_target(gbuffer.depth, rig.c2w, rig.intr)
    raw = isotropic_raw(dist, rig.alpha, rig.intr[:, 0], footprint_px, decode_cfg)
    iso = pixel_gaussians(raw, rig.c2w, rig.intr, decode_cfg)
    _, d = camera.pixel_rays(rig.c2w.float(), rig.intr.float(), H, W)
    n = gbuffer.normal.reshape(-1, 3).float()
    has_n = n.norm(dim=-1) > 0.5
    quats, scales = surfel_shapes(n / n.norm(dim=-1, keepdim=True).clamp_min(1e-8), d.reshape(-1, 3), iso.scales[:, 0])
    surfels = Gaussians(
        iso.means,
        torch.where(has_n[:, None], quats, iso.quats),
        torch.where(has_n[:, None], scales, iso.scales),
        iso.opacities,
    )
    # G-buffer edge pixels may hold depth 0 (no surface sample): no Gaussian there (it would sit at the camera)
    keep = (rig.alpha.reshape(-1) >= 0.5) & (gbuffer.mask.reshape(-1) > 0.5) & (gbuffer.depth.reshape(-1) > 0)
    return surfels, keep


def depth_error(means: torch.Tensor, rig, gbuffer) -> float:
    """Mean absolute error (world units; objects live in the unit sphere) of per-pixel Gaussians' distances along
    their pixels' rays against the G-buffer's, over the rig's foreground pixels that have G-buffer depth.

    means (V*H*W, 3) on the rig's pixel grid (view, row, col order); rig: the input views (c2w (V, 4, 4), intr
    (V, 4), alpha (V, H, W, 1)); gbuffer: their G-buffers (depth (V, H, W, 1) camera z, mask)."""
    from frng import camera
    from frng.priors.backbone import ray_distance_target

    V, H, W = rig.alpha.shape[:3]
    assert means.shape == (V * H * W, 3), (means.shape, rig.alpha.shape)
    o, _ = camera.pixel_rays(rig.c2w.float(), rig.intr.float(), H, W)
    t = (means.float().reshape(V, H, W, 3) - o).norm(dim=-1)
    t_gt = ray_distance_target(gbuffer.depth, rig.c2w, rig.intr)[..., 0]
    fg = (rig.alpha[..., 0] >= 0.5) & (gbuffer.mask[..., 0] > 0.5) & (gbuffer.depth[..., 0] > 0)
    return float((t - t_gt).abs()[fg].mean()) if bool(fg.any()) else math.nan


def mean_image(train_objects: list[PriorObject]) -> np.ndarray:
    imgs = [torch.cat([v.rgb, v.alpha], -1) for o in train_objects for v in o.targets.values()]
    return torch.cat(imgs).mean(0).numpy()


def eval_backbone(seed: int, model, test: list[PriorObject], mean_img: np.ndarray, device="cpu") -> list[dict]:
    """The backbone's rows of the quality ladder on ``test``; ``seed``: the config's data seed (DDIM seeds)."""
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
        t_geo, _, gauss, keep, _, pixels = model.reconstruct(rgb, a, c2w, intr)
        rig_gbuffer = obj.gbuffer.select(torch.arange(obj.rig_views))
        gt_gauss, gt_keep = gt_depth_gaussians(rig, rig_gbuffer, PIXEL_STD, model.decode_config())
        geo_error = {"depth_error": depth_error(gauss.means.cpu(), rig, rig_gbuffer)}
        depth_errors = {"backbone": geo_error, "backbone-geometry+oracle-colour": geo_error}
        depth_errors["gt-depth+oracle-colour"] = {"depth_error": 0.0}
        mr = model.cfg.max_radius_px
        for i, (task, light, out) in enumerate(jobs):
            g = torch.Generator(device=device).manual_seed(seed + i)
            env = obj.envs[light].to(device)[None]
            sh, _ = model.denoise(t_geo, gauss, keep, env, c2w[:nd], intr[:nd], H, W, generator=g, pixels=pixels)
            pred, pa, _ = model.render(gauss, sh, out.c2w.to(device), out.intr.to(device), H, W, keep)
            pred = pred.clamp(0, 1) ** 2.2
            oracle = {
                "gt-depth+oracle-colour": oracle_colour_render(gt_gauss, gt_keep, out, mr),
                "backbone-geometry+oracle-colour": oracle_colour_render(gauss.to("cpu"), keep.cpu(), out, mr),
            }
            for k, name in enumerate(out.names):
                gt = _rgba(out.rgb[k], out.alpha[k])
                base = {"task": task, "object": obj.id, "light": light, "view": name}
                scored = {"backbone": _score(_rgba(pred[k], pa[k]), gt), "mean-image": _score(mean_img, gt)}
                scored |= {method: _score(_rgba(o_rgb[k], o_a[k]), gt) for method, (o_rgb, o_a) in oracle.items()}
                for method, scores in scored.items():
                    rows.append(
                        base | {"method": method} | scores | depth_errors.get(method, {"depth_error": math.nan})
                    )
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
    return IntrinsicPriors(
        normal=facing.clone(),
        depth=mean["depth"].expand(V, H, W, 1).clone(),
        albedo=mean["albedo"].expand(V, H, W, 3).clone(),
        roughness=mean["roughness"].expand(V, H, W, 1).clone(),
        metallic=mean["metallic"].expand(V, H, W, 1).clone(),
        mask=gt.mask,
    )


def eval_idm(idm, test: list[PriorObject], train_objects: list[PriorObject]) -> list[dict]:
    rows = []
    for obj in test:  # on the rig's views, as the models get them (frng.priors.cache.make_idm_priors)
        views = obj.inputs[obj.input_lights[0]].select(range(obj.rig_views))
        gbuffer = obj.gbuffer.select(torch.arange(obj.rig_views))
        pred = view_priors(idm, obj, obj.input_lights[0], range(obj.rig_views))
        rows.append({"object": obj.id, "method": f"idm-{idm.kind}"} | idm_scores(pred, gbuffer))
        rows.append(
            {"object": obj.id, "method": "constant"}
            | idm_scores(constant_priors(train_objects, views, gbuffer), gbuffer)
        )
    return rows
