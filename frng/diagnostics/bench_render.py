"""``frng bench render``: rasterizer and deferred-shading cost on LRM-like pixel-aligned scenes.

For each size (6 views, one Gaussian per input pixel, ~3 px footprints; :func:`frng.render.scenes.pixel_aligned_scene`)
and channel count: forward and forward+backward wall time (median of ``--repeats``), peak memory (CUDA: max allocated;
CPU: the resident-set high-water mark above the scene's baseline, each configuration measured in its own forked
process), Gaussian-pixel pairs per second (pairs = pixels inside the 3-sigma boxes of all visible (view, Gaussian)
instances, per fwd+bwd), and the deferred shading cost per image at the tier's spp (decoder from ``shading``).
"""

from __future__ import annotations

import argparse
import json
import resource

import torch

from frng.device import bf16_ok, median_time


def configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--sizes", type=int, nargs="+", default=[32, 64, 128])
    parser.add_argument("--channels", type=int, nargs="+", default=[3, 32])
    parser.add_argument("--views", type=int, default=6)
    parser.add_argument("--repeats", type=int, default=5, help="timed runs per measurement (median reported)")
    parser.add_argument(
        "--config", default=None, help="pipeline config for the raster/shading sections (defaults otherwise)"
    )
    parser.add_argument("--device", default="auto", choices=["auto", "cpu", "cuda"])
    parser.add_argument("--backend", default=None, help="override raster.backend")
    parser.add_argument("--threads", type=int, default=None, help="torch CPU threads (default: torch's)")
    parser.add_argument("--no-shading", action="store_true", help="skip the deferred shading measurement")
    parser.add_argument("--json", action="store_true", help="one JSON object per line")


def _rss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def _timed(fn, dev, repeats) -> float:
    """Median milliseconds of ``fn()`` after a warm-up (and compile), :func:`frng.device.median_time`."""
    return median_time(fn, dev, repeats)[0] * 1000.0


def run(args: argparse.Namespace) -> int:
    from frng.plan import config as cfgmod
    from frng.plan.sections import config_section
    from frng.render.raster import resolve_backend

    cfg = cfgmod.load(args.config) if args.config else {}
    rc, sc = config_section(cfg, "raster"), config_section(cfg, "shading")
    if args.threads:
        torch.set_num_threads(args.threads)
    dev = torch.device(
        "cuda" if args.device == "cuda" or (args.device == "auto" and torch.cuda.is_available()) else "cpu"
    )
    kw = rc.kwargs()
    if args.backend:
        kw["backend"] = args.backend
    backend = resolve_backend(kw["backend"], dev)
    kw["backend"] = backend
    if not args.json:
        print(
            f"# frng bench render: backend={backend} device={dev} threads={torch.get_num_threads()} "
            f"tile={rc.tile_size} chunk={rc.chunk} spp_infer={sc.spp_infer} spp_train={sc.spp_train}/{sc.spp_grad} "
            f"decoder={sc.decoder_depth}x{sc.decoder_width}"
        )
    jobs = [(size, C) for size in args.sizes for C in args.channels]
    for size, C in jobs:
        if dev.type == "cpu":  # fork: a fresh RSS high-water mark per configuration
            import multiprocessing as mp

            ctx = mp.get_context("fork")
            q = ctx.Queue()
            p = ctx.Process(target=lambda q=q, size=size, C=C: q.put(_measure(args, dev, kw, backend, rc, sc, size, C)))
            p.start()
            row = q.get()
            p.join()
        else:
            row = _measure(args, dev, kw, backend, rc, sc, size, C)
        _print(args, row, sc)
    return 0


def _print(args, row, sc):
    if args.json:
        print(json.dumps(row), flush=True)
        return
    line = (
        f"{row['size']:4d}px x{row['views']} N={row['gaussians']:6d} C={row['channels']:2d}  fwd {row['fwd_ms']:8.1f} ms  "
        f"fwd+bwd {row['fwd_bwd_ms']:8.1f} ms  peak {row['peak_mb']:7.1f} MB  {row['pairs_per_s'] / 1e6:6.1f} M pairs/s"
    )
    if "shade_infer_ms_per_image" in row:
        line += (
            f"  | shading/img ({row['shade_fg_pixels_per_image']} fg px): infer@{sc.spp_infer} "
            f"{row['shade_infer_ms_per_image']} ms, train@{sc.spp_train}/{sc.spp_grad} "
            f"{row['shade_train_ms_per_image']} ms"
        )
    print(line, flush=True)


def _measure(args, dev, kw, backend, rc, sc, size, C) -> dict:
    from frng.render import envmap, rasterize
    from frng.render.project import project_gaussians
    from frng.render.scenes import pixel_aligned_scene
    from frng.render.shading import NeuralDecoder, deferred_shade

    s = pixel_aligned_scene(size, args.views, C)
    s = {k: v.to(dev) for k, v in s.items()}
    params = {k: s[k].clone().requires_grad_() for k in ("means", "quats", "scales", "opacities", "features")}

    def render():
        return rasterize(
            params["means"],
            params["quats"],
            params["scales"],
            params["opacities"],
            params["features"],
            s["c2w"],
            s["intrinsics"],
            size,
            size,
            **kw,
        )

    def fwd():
        with torch.no_grad():
            render()

    def fwd_bwd():
        f, a, d = render()
        (f.sum() + a.sum() + d.sum()).backward()

    if dev.type == "cuda":
        torch.cuda.reset_peak_memory_stats()
    rss0 = _rss_mb()
    fwd_ms = _timed(fwd, dev, args.repeats)
    fb_ms = _timed(fwd_bwd, dev, args.repeats)
    peak = torch.cuda.max_memory_allocated() / 2**20 if dev.type == "cuda" else max(0.0, _rss_mb() - rss0)
    # Gaussian-pixel pairs: instances x pixels inside their 3-sigma box
    with torch.no_grad():
        pr = project_gaussians(
            s["means"], s["quats"], s["scales"], s["c2w"], s["intrinsics"], size, size, opacities=s["opacities"]
        )
        box = (2 * pr.extent[..., 0] + 1) * (2 * pr.extent[..., 1] + 1)
        pairs = float(box[pr.valid].sum())
    row = dict(
        backend=backend,
        device=str(dev),
        threads=torch.get_num_threads(),
        size=size,
        views=args.views,
        gaussians=int(s["means"].shape[0]),
        channels=C,
        fwd_ms=round(fwd_ms, 1),
        fwd_bwd_ms=round(fb_ms, 1),
        peak_mb=round(peak, 1),
        pairs_per_s=round(pairs / (fb_ms / 1000.0)),
    )
    if not args.no_shading and C == args.channels[-1]:
        dec = NeuralDecoder(C, sc.decoder_width, sc.decoder_depth, sc.dir_freqs).to(dev)
        with torch.no_grad():
            f, a, _ = render()
        env = torch.rand(16, 32, 3) * 2
        smp_inf = envmap.sample(envmap.importance_sampler(env), sc.spp_infer, sc.sampling)
        smp_inf = envmap.EnvSamples(*(t.float().to(dev) for t in smp_inf))
        smp_tr = envmap.sample(envmap.importance_sampler(env), sc.spp_train, sc.sampling)
        smp_tr = envmap.EnvSamples(*(t.float().to(dev) for t in smp_tr))
        fg = int((a > sc.alpha_eps).sum())

        def shade(maps, samples, **kw):  # the deferred pass of this scene, with the config's chunks
            chunks = dict(alpha_eps=sc.alpha_eps, chunk=sc.chunk_pixels, chunk_pairs=sc.chunk_pairs)
            return deferred_shade(dec, maps, a, s["c2w"], s["intrinsics"], samples, **chunks, **kw)

        def shade_inf():  # as FRNG.shade at inference: pair-chunked, bf16 when shading.bf16_infer
            with (
                torch.no_grad(),
                torch.autocast(dev.type, dtype=torch.bfloat16, enabled=sc.bf16_infer and bf16_ok(dev)),
            ):
                shade([f], smp_inf)

        fd = f.detach().requires_grad_()

        def shade_train():
            out = shade([fd], smp_tr, spp_grad=sc.spp_grad)
            out.sum().backward()

        reps = max(1, args.repeats // 2)
        row.update(
            shade_fg_pixels_per_image=fg // args.views,
            shade_infer_ms_per_image=round(_timed(shade_inf, dev, reps) / args.views, 1),
            shade_train_ms_per_image=round(_timed(shade_train, dev, reps) / args.views, 1),
            spp_infer=sc.spp_infer,
            spp_train=sc.spp_train,
            spp_grad=sc.spp_grad,
        )
    return row
