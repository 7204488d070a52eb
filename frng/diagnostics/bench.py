"""``frng bench <name>``: benchmarks (not timed tests). Each benchmark is a module with ``configure(parser)`` and
``run(args)``, registered in :data:`BENCHES` (add yours with one line).

Run by hand (``make bench``), never by the workflow. The benchmarks are the modules beside it,
``frng/diagnostics/bench_<name>.py`` (:mod:`frng.diagnostics`)."""

from __future__ import annotations

import argparse
import importlib

# name -> (module, one-line help)
BENCHES: dict[str, tuple[str, str]] = {
    "render": ("frng.diagnostics.bench_render", "rasterizer fwd/fwd+bwd and deferred-shading cost at 32/64/128 px"),
    "relight": (
        "frng.diagnostics.bench_relight",
        "F-RNG vs backbone relighting/reconstruction time at each config's model sizes",
    ),
    "cues": (
        "frng.diagnostics.bench_cues",
        "the backbone's multi-view geometry cues (visual-hull sweep) per call and size",
    ),
    "perceptual": ("frng.diagnostics.bench_perceptual", "training perceptual loss (LPIPS-alex / -vgg) fwd+bwd cost"),
    "heldout": (
        "frng.diagnostics.bench_heldout",
        "held-out relighting quality of trained F-RNG models from the cached tokens (experiments; paired CIs)",
    ),
    "backbone": (
        "frng.diagnostics.bench_backbone",
        "held-out relighting quality and light sensitivity of trained backbones under inference settings (paired CIs)",
    ),
    "export": (
        "frng.diagnostics.bench_export",
        "how well degree-3 SH (frng export-asset) hold a results folder's relit assets: fit PSNR per asset",
    ),
    "train": (
        "frng.diagnostics.bench_train",
        "seconds per training step of the backbone and F-RNG, per thread count, bf16 off/on",
    ),
    "targets-noise": (
        "frng.diagnostics.bench_targets_noise",
        "the curated images' noise floor against a high-spp render; denoising, spp and clamps (aligned metrics)",
    ),
}


def configure(parser: argparse.ArgumentParser) -> None:
    sub = parser.add_subparsers(dest="bench", required=True, metavar="BENCH")
    for name, (module_name, help_) in BENCHES.items():
        p = sub.add_parser(name, help=help_, description=help_)
        module = importlib.import_module(module_name)
        module.configure(p)
        p.set_defaults(_bench_run=module.run)


def run(args: argparse.Namespace) -> int | None:
    return args._bench_run(args)
