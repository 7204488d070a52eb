"""``frng bench cues``: the cost of the backbone's multi-view geometry cues (:func:`frng.priors.multiview.
geometry_cues`: the visual-hull plane sweep, V^2 H W K bilinear reads) per call, per image size.

The backbone computes them for its input views at every training step; the rig views' cues are kept between steps
(:class:`frng.training.backbone.CueCache`), so about half the steps (those that sample the 6 rig views) skip
this cost. Synthetic input (no data needed): the paper's rig (:func:`frng.render.scenes.paper_rig`) looking at a
sphere whose silhouettes are the masks. Median of ``--repeats`` after a warm-up (:func:`frng.device.median_time`).
"""

from __future__ import annotations

import argparse
import json

import torch

from frng.device import median_time, resolve_device


def configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--sizes", type=int, nargs="+", default=[64, 96, 128], help="image side in pixels")
    parser.add_argument("--views", type=int, default=6)
    parser.add_argument("--bins", type=int, default=48, help="samples per ray (backbone.hull_bins)")
    parser.add_argument("--repeats", type=int, default=5, help="timed runs per measurement (median reported)")
    parser.add_argument(
        "--kernel",
        nargs="+",
        default=["auto"],
        choices=["auto", "torch", "native"],
        help="the hull sweep's kernel(s) (frng.priors.multiview.rays_occupancy; the same bytes either way)",
    )
    parser.add_argument("--device", default="auto", choices=["auto", "cpu", "cuda"])
    parser.add_argument("--threads", type=int, default=None, help="torch CPU threads (default: torch's)")
    parser.add_argument("--json", action="store_true", help="one JSON object per line")


def sphere_views(size: int, views: int, radius: float = 0.8, fov_deg: float = 50.0, distance: float = 2.6):
    """(rgb (V, H, W, 3), alpha (V, H, W, 1), c2w (V, 4, 4), intr (V, 4)) of a sphere of ``radius`` seen by the
    rig: alpha 1 where a pixel's ray hits it, rgb a fixed random colour per pixel there (premultiplied)."""
    from frng.priors.multiview import ray_sphere
    from frng.render.scenes import rig_rays

    c2w, intr, o, d = rig_rays(size, views, fov_deg, distance)
    alpha = ray_sphere(o, d, radius)[2].float()[..., None]
    rgb = torch.rand(views, size, size, 3, generator=torch.Generator().manual_seed(0)) * alpha
    return rgb, alpha, c2w, intr


def run(args: argparse.Namespace) -> int:
    from frng.priors.multiview import geometry_cues

    if args.threads:
        torch.set_num_threads(args.threads)
    dev = resolve_device(args.device)
    if not args.json:
        print(f"# frng bench cues: device={dev} threads={torch.get_num_threads()} views={args.views} bins={args.bins}")
    for size, kernel in [(s, k) for s in args.sizes for k in args.kernel]:
        views = [t.to(dev) for t in sphere_views(size, args.views)]
        sec, _ = median_time(
            lambda v=views, k=kernel: geometry_cues(*v, 1.0, 4.5, args.bins, kernel=k), dev, args.repeats
        )
        row = dict(
            size=size,
            kernel=kernel,
            views=args.views,
            bins=args.bins,
            device=str(dev),
            threads=torch.get_num_threads(),
            ms=round(sec * 1000.0, 1),
            fg_fraction=round(float(views[1].mean()), 3),
        )
        if args.json:
            print(json.dumps(row), flush=True)
        else:
            print(
                f"{size:4d}px x{args.views}  fg {row['fg_fraction']:.2f}  {kernel:6s}  geometry_cues {row['ms']:8.1f} ms",
                flush=True,
            )
    return 0
