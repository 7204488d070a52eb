"""``frng bench train``: seconds per training step of the backbone and of F-RNG at a config's sizes, per thread count
and with bf16 autocast off / on, on the machine it runs on (named in the first line).

Each measurement is a separate process (the thread count is fixed before torch runs an op,
:func:`frng.device.training_threads`) that runs the real trainer (:func:`frng.training.backbone.train`,
:func:`frng.training.frng_trainer.train`) for ``--skip + --steps`` steps on the first ``--objects`` training objects of the
config's results folder, in a temporary folder, and reports the median and the mean of the last ``--steps`` steps'
times (from its ``loss.csv``): the mean is what sets a training run's minutes (the backbone's steps are bimodal:
those that sample a random view subset sweep its visual hull, the rig views' sweeps are cached). It needs the folder's curated data (backbone) and, for F-RNG, its backbone model and caches: run it
after ``make reproduce`` (or ``make smoke`` with ``--config config/smoke.yaml``). Nothing is written under the
results folder.

What the timed steps are: the backbone's with its perceptual term on (the tier's steps after
``backbone.train.perceptual_after``, the larger share) and its multi-view cue cache warm for the rig views (a few
objects, so the ``--skip`` warm-up steps fill it, as the long run's first steps do); F-RNG's ``--variant`` step as
the rule ``train`` runs it (its per-object pixel maps kept after the first visit). bf16 ``on`` is what the config
switch means (:func:`frng.device.bf16_ok`): on a CPU without native bf16 (AMX / AVX512-BF16) it runs in float32 and
the row says ``n/a``.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

from frng.plan import config as frng_config

MODELS = ("backbone", "frng")
BF16 = ("off", "on")


def configure(parser: argparse.ArgumentParser) -> None:
    frng_config.add_config_argument(parser)
    parser.add_argument("--models", nargs="+", default=list(MODELS), choices=MODELS)
    parser.add_argument("--variant", default="full", help="the F-RNG variant whose step is timed (default full)")
    parser.add_argument("--threads", type=int, nargs="+", default=[1, 2], help="torch intra-op threads per run")
    parser.add_argument("--bf16", nargs="+", default=list(BF16), choices=BF16, help="autocast off / on")
    parser.add_argument("--steps", type=int, default=20, help="timed steps per run (median reported)")
    parser.add_argument("--skip", type=int, default=8, help="untimed warm-up steps first (caches filled)")
    parser.add_argument("--objects", type=int, default=4, help="training objects the runs draw from")
    parser.add_argument("--json", action="store_true", help="one JSON object per line")
    parser.add_argument("--one", help=argparse.SUPPRESS)  # MODEL:THREADS:BF16, the child process's measurement


def _step_seconds(loss_csv: Path, skip: int) -> list[float]:
    """Per-step seconds after the first ``skip`` steps, from a trainer's ``loss.csv`` (``elapsed_s`` column)."""
    import pandas as pd

    elapsed = pd.read_csv(loss_csv)["elapsed_s"].to_numpy()
    return [float(b - a) for a, b in zip(elapsed[skip:-1], elapsed[skip + 1 :])]


def _measure(config, model: str, bf16: bool, args: argparse.Namespace, out: Path) -> list[float]:
    """Run ``model``'s trainer for ``skip + steps`` steps into ``out``; the timed steps' seconds."""
    from frng.plan import catalog
    from frng.plan.layout import Layout, TrainingFolder

    total = args.skip + args.steps + 1
    ids = catalog.plan(config).split("train")[: args.objects]
    if not ids:
        raise SystemExit(f"frng bench train: the config's training split is empty ({config.results})")
    if model == "backbone":
        from frng.priors.dataset import load_split
        from frng.training.backbone import train

        tcfg = dataclasses.replace(config.backbone.train, bf16=bf16, perceptual_after=0, checkpoint_every=total + 1)
        section = dataclasses.replace(config.backbone, train=tcfg)
        train(
            section,
            config.model.patch_size,
            config.device,
            config.model_seed,
            load_split(config.results, ids),
            out,
            steps=total,
        )
    else:
        from frng.training.frng_trainer import ModelSections, TrainRun, train

        backbone = Path(Layout(config.results).backbone_model())
        if not backbone.is_file():
            raise SystemExit(f"frng bench train: no backbone model {backbone}: run the pipeline up to it first")
        tcfg = dataclasses.replace(config.train, bf16=bf16, checkpoint_every=total + 1)
        job = TrainRun(config.results, config.model_seed, config.device, config.idm.kind, tuple(ids))
        train(ModelSections.of(config), tcfg, job, args.variant, out, backbone, steps=total)
    return _step_seconds(Path(TrainingFolder(out).curve()), args.skip)


def _child(args: argparse.Namespace) -> int:
    import torch

    from frng.device import bf16_ok, resolve_device
    from frng.typedconfig import typed

    model, threads, bf16 = args.one.split(":")
    config = typed(frng_config.load(args.config))
    device = resolve_device(config.device)
    on = bf16 == "on"
    with tempfile.TemporaryDirectory(prefix="frng-bench-train-") as tmp:
        secs = _measure(config, model, on, args, Path(tmp))
    row = {
        "model": model,
        "threads": torch.get_num_threads(),
        "bf16": ("on" if bf16_ok(device) else "n/a") if on else "off",
        "device": str(device),
        "step_ms": round(1000 * statistics.median(secs), 1),
        "step_ms_mean": round(1000 * statistics.fmean(secs), 1),
        "step_ms_min": round(1000 * min(secs), 1),
        "steps": len(secs),
    }
    print("BENCH " + json.dumps(row), flush=True)
    return 0


def run(args: argparse.Namespace) -> int:
    if args.one:
        return _child(args)
    from frng.device import bf16_ok
    from frng.report.results_page import cpu_model

    if args.steps < 2 or args.skip < 0 or args.objects < 1:
        raise SystemExit("frng bench train: --steps >= 2, --skip >= 0 and --objects >= 1")
    if not args.json:
        native = "native bf16" if bf16_ok("cpu") else "no native bf16"
        print(
            f"# frng bench train: {cpu_model()}, {native}; config {args.config}; median of {args.steps} steps after {args.skip} (x: against each model's first row)"
        )
    base: dict[str, float] = {}
    for model in args.models:
        for threads in args.threads:
            for bf16 in args.bf16:
                cmd = [sys.executable, "-m", "frng", "bench", "train", "--config", args.config, "--variant",
                       args.variant, "--steps", str(args.steps), "--skip", str(args.skip), "--objects",
                       str(args.objects), "--one", f"{model}:{threads}:{bf16}"]  # fmt: skip
                env = {**os.environ, "FRNG_TORCH_THREADS": str(threads)}
                proc = subprocess.run(cmd, env=env, capture_output=True, text=True)
                line = next((l for l in proc.stdout.splitlines() if l.startswith("BENCH ")), None)
                if proc.returncode != 0 or line is None:
                    tail = (proc.stderr or proc.stdout).strip().splitlines()[-1:] or ["no output"]
                    raise SystemExit(f"frng bench train: {model} at {threads} thread(s), bf16 {bf16}: {tail[0]}")
                row = json.loads(line[len("BENCH ") :])
                ref = base.setdefault(model, row["step_ms"])  # the first row of each model: the reference
                row["speedup"] = round(ref / row["step_ms"], 2)
                if args.json:
                    print(json.dumps(row), flush=True)
                else:
                    print(
                        f"{model:9s} threads {row['threads']}  bf16 {row['bf16']:3s}  {row['step_ms']:8.1f} ms/step"
                        f"  (mean {row['step_ms_mean']:.1f}, min {row['step_ms_min']:.1f})  {1000 / row['step_ms']:5.2f}"
                        f" steps/s  x{row['speedup']:.2f}",
                        flush=True,
                    )
    return 0
