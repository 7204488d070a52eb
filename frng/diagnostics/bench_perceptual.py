"""``frng bench perceptual``: the training perceptual loss's cost (``frng.perceptual.PerceptualLoss``,
LPIPS-alex vs LPIPS-vgg), forward+backward through the prediction, per image size and batch.

A training step of F-RNG evaluates L_per on ``train.target_views`` renders (batch 1), the backbone's on
``backbone.train.supervision_views``: ``--batches 2`` is a default-tier step's share. Median of ``--repeats`` after a
warm-up (:func:`frng.device.median_time`); random images (the cost does not depend on the content).
"""

from __future__ import annotations

import argparse
import json

import torch

from frng.device import median_time, resolve_device
from frng.perceptual import NETS


def configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--nets", nargs="+", default=list(NETS), choices=NETS)
    parser.add_argument("--sizes", type=int, nargs="+", default=[64, 128], help="image side in pixels (>= 32)")
    parser.add_argument("--batches", type=int, nargs="+", default=[2], help="images per loss call")
    parser.add_argument("--repeats", type=int, default=5, help="timed runs per measurement (median reported)")
    parser.add_argument("--device", default="auto", choices=["auto", "cpu", "cuda"])
    parser.add_argument("--threads", type=int, default=None, help="torch CPU threads (default: torch's)")
    parser.add_argument("--json", action="store_true", help="one JSON object per line")


def run(args: argparse.Namespace) -> int:
    from frng.perceptual import PerceptualLoss

    if args.threads:
        torch.set_num_threads(args.threads)
    dev = resolve_device(args.device)
    if any(s < 32 for s in args.sizes):
        raise SystemExit(f"frng bench perceptual: --sizes must be >= 32 px (LPIPS' five taps), got {args.sizes}")
    if not args.json:
        print(f"# frng bench perceptual: device={dev} threads={torch.get_num_threads()} repeats={args.repeats}")
    gen = torch.Generator().manual_seed(0)
    for net in args.nets:
        loss = PerceptualLoss("lpips", net=net, srgb=True).to(dev)
        for size in args.sizes:
            for batch in args.batches:
                pred = torch.rand(batch, 3, size, size, generator=gen).to(dev).requires_grad_()
                target = torch.rand(batch, 3, size, size, generator=gen).to(dev)

                def fwd_bwd(pred=pred, target=target, loss=loss):
                    pred.grad = None
                    loss(pred, target).backward()

                sec, _ = median_time(fwd_bwd, dev, args.repeats)
                row = dict(
                    net=net,
                    size=size,
                    batch=batch,
                    device=str(dev),
                    threads=torch.get_num_threads(),
                    fwd_bwd_ms=round(sec * 1000.0, 1),
                )
                if args.json:
                    print(json.dumps(row), flush=True)
                else:
                    print(f"lpips-{net:5s} {size:4d}px x{batch}  fwd+bwd {row['fwd_bwd_ms']:8.1f} ms", flush=True)
    return 0
