"""``frng bench relight``: F-RNG's relighting cost vs the backbone's, at each config's architecture sizes.

The relight stage (``frng relight``) times both methods on the trained default-tier models; this benchmark checks
the speed claim where model size matters: it builds the backbone, the learned IDM and F-RNG with the sizes of each
given config (``config/paper.yaml``: RelitLRM's 24 + 8 layers x 1024, MaterialFormer 4 x 1024, decoder 4 x 256,
128 spp) with untrained weights (timing does not depend on the weights' values), on a synthetic object
(a textured sphere seen by the paper's 6-view rig; one Gaussian per foreground input pixel as the backbone makes)
at a resolution this machine can afford, and measures, with the same code paths as the relight stage:

- ``reconstruction_s`` (F-RNG): backbone geometry + appearance tokens under the input light (one DDIM pass)
  + IDM priors + F-RNG reconstruction; the per-part times are reported too;
- ``frng_ms_per_image``: one new image (rasterize its view's G-buffer + shade under one light);
- ``frng_ms_per_image_amortised``: rasterize the target views once, shade under ``--lights`` lights (what the
  relight stage does), per image;
- ``backbone_ms_per_image``: one full denoising pass per light + rendering the target views, per image;
- ``speedup``: backbone / F-RNG (single new image), ``speedup_amortised``.

- the shading's roofline: the decoder's MLP FLOPs per decoded (pixel, sample) pair (only lit pairs are decoded,
  :meth:`frng.render.shading.NeuralDecoder._reflectance`), the GFLOP per image and the GFLOP/s the shading achieved,
  against the measured peak of this machine for the same matrix product shapes (``shading.chunk_pairs`` rows x
  decoder width, in the dtype the decoder runs in).

Each ``--resolution`` is timed ``--passes`` times (median reported) after ONE untimed warm-up pass of the whole
chain at a small resolution (two patches a side): at 256-512 px a second full-size pass would double hours of
CPU time for no information. ``--device cuda`` where a GPU is present (gsplat backend if installed); ``--bf16``
runs the transformers and the decoder under bf16 autocast (CPU: AMX; CUDA); the decoder also uses bf16 when the
config's ``shading.bf16_infer`` is true.
"""

from __future__ import annotations

import argparse
import json
import time
from collections.abc import Iterator
from contextlib import nullcontext
from dataclasses import replace
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import torch

from frng.device import bf16_ok, median_time, synchronize
from frng.typedconfig import Config, typed

DEFAULT_CONFIGS = ["config/config.yaml", "config/paper.yaml"]


def configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--configs",
        nargs="+",
        default=DEFAULT_CONFIGS,
        help="pipeline configs whose architecture sizes (backbone, idm, frng, shading) are timed",
    )
    parser.add_argument(
        "--resolution", type=int, nargs="+", default=[64], help="image sizes (multiples of the patch size), each timed"
    )
    parser.add_argument("--lights", type=int, default=3, help="lights per relighting (amortised figure)")
    parser.add_argument("--target-views", type=int, default=4)
    parser.add_argument("--spp", type=int, default=None, help="light samples per pixel (default shading.spp_infer)")
    parser.add_argument(
        "--passes",
        "--repeats",
        dest="passes",
        type=int,
        default=3,
        help="timed passes per resolution (median reported), after one untimed warm-up pass at a small resolution",
    )
    parser.add_argument("--device", default="auto", choices=["auto", "cpu", "cuda"])
    parser.add_argument("--threads", type=int, default=None, help="torch CPU threads (default: torch's)")
    parser.add_argument("--bf16", action="store_true", help="bf16 autocast for the transformers")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--json", action="store_true", help="one JSON object per config")


def synthetic_object(config: Config, res: int, n_targets: int, seed: int, dev: torch.device) -> dict:
    """A checker-textured Lambertian sphere (radius 0.6) under a fixed directional light, seen by the 6-view rig.

    Returns rgb (6, H, W, 3) and alpha (6, H, W, 1) linear premultiplied, c2w (6, 4, 4), intr (6, 4), and the
    target cameras t_c2w (Vt, 4, 4), t_intr (Vt, 4)."""
    from frng import camera
    from frng.data import rig

    rng = np.random.default_rng(seed)
    r = config.render
    args = (r.camera_distance, r.fov_deg, res)
    ins, tgts = rig.input_views(rng, 0, *args), rig.target_views(rng, n_targets, *args)

    def cams(views):
        return (
            torch.tensor(np.stack([v.c2w for v in views]), dtype=torch.float32, device=dev),
            torch.tensor(np.stack([v.intrinsics for v in views]), dtype=torch.float32, device=dev),
        )

    c2w, intr = cams(ins)
    o, d = camera.pixel_rays(c2w, intr, res, res)
    b = (o * d).sum(-1)
    disc = b * b - ((o * o).sum(-1) - 0.36)
    hit = disc > 0
    t = -b - disc.clamp_min(0).sqrt()
    p = o + t[..., None] * d
    n = p / p.norm(dim=-1, keepdim=True)
    checker = (torch.floor(p[..., 0] * 6) + torch.floor(p[..., 1] * 6) + torch.floor(p[..., 2] * 6)) % 2
    albedo = torch.stack([0.2 + 0.6 * checker, 0.5 - 0.2 * checker, 0.3 + 0.1 * checker], -1)
    light = torch.tensor([0.5, 0.3, 0.8], device=dev)
    shade = 0.15 + (n * light / light.norm()).sum(-1).clamp_min(0)
    alpha = hit.float()[..., None]
    t_c2w, t_intr = cams(tgts)
    return {
        "rgb": albedo * shade[..., None] * alpha,
        "alpha": alpha,
        "c2w": c2w,
        "intr": intr,
        "t_c2w": t_c2w,
        "t_intr": t_intr,
    }


def synthetic_env(height: int, seed: int, dev: torch.device) -> torch.Tensor:
    """A smooth sky-like HDR map (height, 2 * height, 3) with a sun blob (its position from ``seed``)."""
    from frng.render import envmap

    g = torch.Generator().manual_seed(seed)
    dirs = envmap.pixel_directions(height, 2 * height)
    sun = torch.nn.functional.normalize(torch.randn(3, generator=g).abs() * torch.tensor([1.0, 1.0, 2.0]), dim=0)
    sky = 0.3 + 0.7 * dirs[..., 2:3].clamp_min(0) * torch.tensor([0.5, 0.7, 1.0])
    blob = 50.0 * torch.exp(((dirs * sun).sum(-1, keepdim=True) - 1.0) / 0.002)
    return (sky + blob).float().to(dev)


def build(path: str, args: argparse.Namespace, dev: torch.device) -> SimpleNamespace:
    """One config's untrained models at its architecture sizes, built once for every resolution: a namespace of
    path, config, backbone, idm, frng and shading."""
    from frng.model.composed import FRNG
    from frng.plan import config as frng_config
    from frng.priors import backbone as backbone_mod
    from frng.priors import freeze
    from frng.priors import idm as idm_mod
    from frng.priors.backbone_config import backbone_config
    from frng.priors.idm import idm_config
    from frng.training.frng_trainer import ModelSections, variant_config

    config = typed(frng_config.load(path))
    patch = int(config.model.patch_size)
    for res in args.resolution:
        if res % patch:
            raise SystemExit(
                f"frng bench relight: --resolution {res} is not a multiple of the patch size {patch} ({path})"
            )
    torch.manual_seed(args.seed)
    backbone = freeze(backbone_mod.build(backbone_config(config.backbone, config.model.patch_size)).to(dev))
    idm = freeze(
        idm_mod.build(idm_config(config.idm, config.model.patch_size, config.backbone.near, config.backbone.far)).to(
            dev
        )
    )
    fcfg, _ = variant_config(ModelSections.of(config), "full", backbone.cfg.to_dict())
    shading = config.shading
    if args.bf16:
        shading = replace(shading, bf16_infer=True)
    model = FRNG.from_backbone(fcfg, backbone, shading=shading).to(dev).eval()
    return SimpleNamespace(path=path, config=config, backbone=backbone, idm=idm, frng=model, shading=shading)


def matmul_peak_gflops(rows: int, width: int, dtype: torch.dtype, dev: torch.device, seconds: float = 1.0) -> float:
    """GFLOP/s of (rows, width) @ (width, width) products in ``dtype`` on ``dev``, repeated for about ``seconds``
    after one warm-up: the peak a decoder layer of that shape can reach on this machine (roofline's ceiling)."""
    a = torch.randn(rows, width, device=dev).to(dtype)
    w = torch.randn(width, width, device=dev).to(dtype)
    with torch.no_grad():
        torch.mm(a, w)
        n, t0 = 0, time.perf_counter()
        while True:
            torch.mm(a, w)
            n += 1
            synchronize(dev)
            if time.perf_counter() - t0 >= seconds:
                break
    return 2.0 * rows * width * width * n / (time.perf_counter() - t0) / 1e9


def measure(m: SimpleNamespace, res: int, args: argparse.Namespace, dev: torch.device, passes: int) -> dict:
    """One resolution's timings (median of ``passes`` timed runs per measurement, no warm-up of its own)."""
    from frng.priors.cache import geometry_entry
    from frng.priors.dataset import Views
    from frng.render.shading import lit_pairs

    config, backbone, idm, model, shading = m.config, m.backbone, m.idm, m.frng, m.shading
    spp = args.spp or int(config.shading.spp_infer)
    obj = synthetic_object(config, res, args.target_views, args.seed, dev)
    env_h = max(16, int(config.envmaps.width) // 2)
    env_in = synthetic_env(env_h, args.seed, dev)
    envs = [synthetic_env(env_h, args.seed + 1 + i, dev) for i in range(args.lights)]
    rgb, alpha, c2w, intr, t_c2w, t_intr = (obj[k] for k in ("rgb", "alpha", "c2w", "intr", "t_c2w", "t_intr"))
    nd = backbone.cfg.den_views
    Vt = t_c2w.shape[0]
    amp = torch.autocast(dev.type, dtype=torch.bfloat16) if args.bf16 else nullcontext()

    def gen(seed):
        return torch.Generator(device=dev).manual_seed(seed)

    def timed(fn):
        return median_time(fn, dev, passes, warmup=False)

    with torch.no_grad(), amp:
        t_geo_s, recon = timed(lambda: backbone.reconstruct(rgb, alpha, c2w, intr))
        t_geo, _, gauss, keep, _, pixels = recon
        t_app_s, (sh_in, t_app) = timed(
            lambda: backbone.denoise(
                t_geo, gauss, keep, env_in[None], c2w[:nd], intr[:nd], res, res, generator=gen(0), pixels=pixels
            )
        )
        views = Views([f"in_{i:02d}" for i in range(6)], rgb, alpha, c2w, intr)
        t_idm_s, priors = timed(lambda: idm.predict(views.rgb, views.alpha, views.c2w, views.intr))
        # the far-side completion (back_*) is part of the backbone's reconstruction, as in live relighting
        t_back_s, bv = timed(lambda: geometry_entry(backbone, recon, alpha, c2w, intr))
        bv["light0.t_app"] = t_app[0].float()
        images = torch.cat([rgb, alpha], -1)
        t_frng_s, rec = timed(lambda: model.reconstruct(bv, 0, priors, images))
    with torch.no_grad():
        t_ras_s, raster = timed(lambda: model.rasterize(rec, t_c2w, t_intr, res, res))
        t_shade_s, _ = timed(lambda: [model.shade(raster, e, spp, generator=gen(i)) for i, e in enumerate(envs)])
        # the pairs the decoder decodes: the same sample sets shade() draws
        # a cosine decoder decodes the pairs above each normal's horizon; the paper's decoder every pair
        counts = [
            lit_pairs(raster[0], raster[1], model.light_samples(e, spp, gen(i)).dirs, shading.alpha_eps)
            if model.decoder.cosine
            else (n := int((raster[1][..., 0] > shading.alpha_eps).sum()), n * spp)
            for i, e in enumerate(envs)
        ]

    def backbone_relight():
        with torch.no_grad(), amp:
            for i, e in enumerate(envs):
                sh, _ = backbone.denoise(
                    t_geo, gauss, keep, e[None], c2w[:nd], intr[:nd], res, res, generator=gen(i), pixels=pixels
                )
                backbone.render(gauss, sh, t_c2w, t_intr, res, res, keep)

    t_bb_s, _ = timed(backbone_relight)
    L = len(envs)
    raster_ms, shade_ms = 1000 * t_ras_s / Vt, 1000 * t_shade_s / (L * Vt)
    frng_ms, frng_amort_ms = raster_ms + shade_ms, shade_ms + raster_ms / L
    bb_ms = 1000 * t_bb_s / (L * Vt)
    pix_img = sum(c[0] for c in counts) / (L * Vt)
    pairs_img = sum(c[1] for c in counts) / (L * Vt)
    per_pair, per_pixel = model.decoder.flops() if hasattr(model.decoder, "flops") else (0, 0)
    gflop_img = (pairs_img * per_pair + pix_img * per_pixel) / 1e9
    return {
        "resolution": res,
        "passes": passes,
        "spp": spp,
        "lights": L,
        "target_views": Vt,
        "gaussians": int(rec.gaussians.means.shape[0]),
        "reconstruction_s": t_geo_s + t_back_s + t_app_s + t_idm_s + t_frng_s,
        "backbone_geometry_s": t_geo_s + t_back_s,
        "backbone_appearance_s": t_app_s,
        "idm_s": t_idm_s,
        "frng_s": t_frng_s,
        "raster_ms_per_view": raster_ms,
        "shade_ms_per_image": shade_ms,
        "frng_ms_per_image": frng_ms,
        "frng_ms_per_image_amortised": frng_amort_ms,
        "backbone_ms_per_image": bb_ms,
        "speedup": bb_ms / frng_ms,
        "speedup_amortised": bb_ms / frng_amort_ms,
        "pixels_per_image": pix_img,
        "lit_pairs_per_image": pairs_img,
        "lit_fraction": pairs_img / max(1.0, pix_img * spp),
        "decoder_flops_per_pair": per_pair,
        "shade_gflop_per_image": gflop_img,
        "shade_gflops": gflop_img / max(1e-9, shade_ms / 1000),
    }


def bench_config(path: str, args: argparse.Namespace, dev: torch.device) -> Iterator[dict]:
    """Every ``--resolution`` of one config, after one untimed warm-up pass at two patches a side; each row as soon
    as it is measured (at the paper's sizes on a CPU one resolution takes minutes)."""
    m = build(path, args, dev)
    patch = int(m.config.model.patch_size)
    measure(m, 2 * patch, args, dev, passes=1)  # warm-up: the same code paths, seconds instead of minutes
    sc = m.shading
    dtype = torch.bfloat16 if sc.bf16_infer and bf16_ok(dev) else torch.float32
    width = int(sc.decoder_width)
    peak = matmul_peak_gflops(int(sc.chunk_pairs), width, dtype, dev)
    n_params = lambda mod: sum(p.numel() for p in mod.parameters())  # noqa: E731
    head = {
        "config": path,
        "tier": m.config.tier,
        "device": str(dev),
        "threads": torch.get_num_threads(),
        "bf16": bool(args.bf16),
        "bf16_decoder": sc.bf16_infer,
        "backbone_params_m": n_params(m.backbone) / 1e6,
        "frng_params_m": n_params(m.frng) / 1e6,
        "matmul_peak_gflops": peak,
        "matmul_shape": f"({int(sc.chunk_pairs)}, {width}) @ ({width}, {width}) {str(dtype).replace('torch.', '')}",
    }
    for res in args.resolution:
        yield {**head, **measure(m, res, args, dev, args.passes)}


def run(args: argparse.Namespace) -> int:
    from frng.device import resolve_device

    if args.threads:
        torch.set_num_threads(args.threads)
    dev = resolve_device(args.device)
    for path in args.configs:
        if not Path(path).exists():
            raise SystemExit(f"frng bench relight: config {path} does not exist")
    for path in args.configs:
        for r in bench_config(path, args, dev):
            print(json.dumps(r) if args.json else report(r), flush=True)
    return 0


def report(r: dict) -> str:
    """The human-readable lines of one (config, resolution) measurement."""
    pct = 100 * r["shade_gflops"] / max(1e-9, r["matmul_peak_gflops"])
    return "\n".join(
        [
            f"== {r['tier']} sizes ({r['config']}) on {r['device']} ({r['threads']} threads{', bf16' if r['bf16'] else ''}), "
            f"{r['resolution']} px, {r['spp']} spp, {r['lights']} lights x {r['target_views']} views, "
            f"{r['gaussians']} Gaussians, median of {r['passes']} pass(es); backbone {r['backbone_params_m']:.1f} M "
            f"params, F-RNG {r['frng_params_m']:.1f} M params",
            f"  F-RNG reconstruction {r['reconstruction_s']:.2f} s (backbone geometry {r['backbone_geometry_s']:.2f}, "
            f"appearance {r['backbone_appearance_s']:.2f}, IDM {r['idm_s']:.2f}, F-RNG {r['frng_s']:.2f})",
            f"  F-RNG relighting {r['frng_ms_per_image']:.1f} ms/image (raster {r['raster_ms_per_view']:.1f} + "
            f"shade {r['shade_ms_per_image']:.1f}); amortised over {r['lights']} lights "
            f"{r['frng_ms_per_image_amortised']:.1f} ms/image",
            f"  backbone relighting {r['backbone_ms_per_image']:.1f} ms/image -> speed-up {r['speedup']:.1f}x "
            f"({r['speedup_amortised']:.1f}x amortised)",
            f"  shading roofline: {r['pixels_per_image']:.0f} px x {r['spp']} spp, {100 * r['lit_fraction']:.0f} % of "
            f"the pairs lit and decoded, {r['decoder_flops_per_pair'] / 1e3:.0f} kFLOP a pair -> "
            f"{r['shade_gflop_per_image']:.2f} GFLOP/image at {r['shade_gflops']:.1f} GFLOP/s = {pct:.0f} % of "
            f"{r['matmul_peak_gflops']:.1f} GFLOP/s measured for {r['matmul_shape']} products",
        ]
    )
