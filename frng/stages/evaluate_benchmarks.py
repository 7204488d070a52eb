"""Stage ``frng evaluate-benchmarks`` (rule ``evaluate_benchmarks``): the relit benchmark objects scored with each
benchmark's PUBLISHED protocol (:mod:`frng.benchmarks.protocols`), and the comparison table.

For every imported object (``meta.json`` ``benchmark``: its layout and protocol) and every run of it that
``frng relight`` wrote (``{results}/relight/{run}/{obj}/run.json``; by default F-RNG ``full`` and ``backbone``),
every (light, view) pair that has a ground truth (``benchmark.pairs``: benchmarks with one light per test view,
Stanford-ORB and OWL, have fewer pairs than lights x views) is scored with the object's protocol; OWL's gets the
view's exposure (``benchmark.exposures``). Writes

- ``{results}/metrics/benchmarks_per_image.csv``: benchmark, protocol, object, run, method, light, view and the
  protocol's metrics (``psnr`` is the benchmark's headline PSNR: PSNR-H for Stanford-ORB, with ``psnr_l``);
- ``{results}/tables/benchmarks.{csv,md,tex}``: F-RNG vs the backbone, one row per (benchmark, method), means over
  the images, the protocol named in its own column and in the caption.
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path

from frng import io
from frng.plan import config as frng_config
from frng.plan.layout import Layout, RelightFolder
from frng.typedconfig import typed

TABLE_COLUMNS = ("benchmark", "protocol", "method", "psnr", "psnr_l", "ssim", "lpips", "images")
PROTOCOL_NAMES = {
    "tensoir": "TensoIR: white background, whole image, no scaling",
    "nerf-synthetic": "NeRF: white background, whole image, no scaling",
    "orb": "Stanford-ORB: scale-invariant PSNR-H / PSNR-L over an eroded mask",
    "owl": "OWL: fitted exposure + bounded colour balance, masked PSNR/SSIM/LPIPS",
}


def score_object(results: Path, oid: str, runs: list[str], lpips: bool = True) -> list[dict]:
    from frng.benchmarks.protocols import score

    L = Layout(results)
    meta = io.read_json(L.object_meta(oid))
    bench = meta.get("benchmark")
    if not isinstance(bench, dict):
        raise ValueError(f"{L.object_meta(oid)}: not an imported benchmark object (no 'benchmark' key)")
    rows = []
    for run in runs:
        folder = RelightFolder(L.relight_run(run, oid))
        info = io.read_json(folder.record())
        for light, view in bench["pairs"]:
            pred = io.read_rgba(folder.image(light, view))
            gt = io.read_rgba(L.object_image(oid, "targets", light, view))
            exposure = bench.get("exposures", {}).get(f"{light}/{view}", 0.0)
            m = score(bench["protocol"], pred, gt, exposure=exposure, lpips=lpips)
            rows.append(
                {
                    "benchmark": bench["layout"],
                    "protocol": bench["protocol"],
                    "object": oid,
                    "run": run,
                    "method": info.get("method", run),
                    "light": light,
                    "view": view,
                }
                | m
            )
    return rows


def table(df):
    import pandas as pd

    cols = [c for c in ("psnr", "psnr_l", "ssim", "lpips") if c in df.columns]
    out = df.groupby(["benchmark", "protocol", "method"], sort=False)[cols].mean().reset_index()
    out["images"] = df.groupby(["benchmark", "protocol", "method"], sort=False).size().values
    for c in TABLE_COLUMNS:
        if c not in out.columns:
            out[c] = math.nan
    return pd.DataFrame(out[list(TABLE_COLUMNS)])


def evaluate(
    config, objects: list[str], runs: list[str], metrics_dir: Path, tables_dir: Path, lpips: bool = True
) -> tuple[Path, dict]:
    from frng import metrics as M
    from frng.report.tables import write_table

    config = typed(config)
    rows = []
    for oid in objects:
        rows += score_object(Path(config.results), oid, runs, lpips)
    if not rows:
        raise ValueError("frng evaluate-benchmarks: no benchmark objects to score")
    df = M.to_frame(rows)
    per_image = M.write_csv(df, Path(metrics_dir) / "benchmarks_per_image.csv")
    t = table(df)
    used = ", ".join(f"{p} ({PROTOCOL_NAMES.get(p, p)})" for p in dict.fromkeys(t["protocol"]))
    caption = (
        f"F-RNG vs the backbone on the public benchmarks ({config.tier} tier); each row scored with its "
        f"benchmark's published protocol: {used}"
    )
    out = write_table(
        t, Path(tables_dir) / "benchmarks", best_within=["benchmark"], caption=caption, label="tab:benchmarks"
    )
    return per_image, out


# The config keys this stage reads (frng.plan.digests: its rule's digest): the runs and the protocol
CONFIG_READS = ("benchmarks", "eval", "tier")


def configure(parser: argparse.ArgumentParser) -> None:
    frng_config.add_config_argument(parser)
    parser.add_argument("--objects", nargs="*", help="imported objects (default: the config's benchmarks)")
    parser.add_argument("--runs", nargs="*", default=["full", "backbone"], help="relighting runs to score")
    parser.add_argument("--metrics", help="metrics folder (default {results}/metrics)")
    parser.add_argument("--tables", help="tables folder (default {results}/tables)")
    parser.add_argument("--no-lpips", action="store_true", help="skip LPIPS (faster)")


def run(args: argparse.Namespace) -> int:
    from frng.benchmarks import entries

    config = typed(frng_config.load(args.config))
    L = Layout(config.results)
    objects = args.objects or [e["id"] for e in entries(config)]
    per_image, out = evaluate(
        config,
        objects,
        args.runs,
        Path(args.metrics or L.metrics_dir()),
        Path(args.tables or L.tables_dir()),
        lpips=not args.no_lpips,
    )
    print(f"evaluate-benchmarks: wrote {per_image} and {', '.join(str(p) for p in out.values())}")
    print(Path(out["md"]).read_text() if "md" in out else "")
    return 0
