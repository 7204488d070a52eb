"""Stage ``frng baseline-tables`` (rule ``baseline_tables``): the baselines' tables ``vs_dense`` (paper Table 2),
``vs_image_based`` (Table 3) and ``views_nvs`` (the supplementary's views table) as ``{results}/tables/{name}.{csv,md,
tex}``, and one comparison figure per table ``{results}/figures/baselines/{name}.png``
(:mod:`frng.report.baseline_tables`), from ``frng baseline-eval``'s ``{results}/metrics/baselines_per_image.csv`` and
``baselines_timing.csv``.

Config keys read: ``results``, ``tier``, ``eval.background`` (captions, figure compositing), and for the figures the
runs ``frng baseline-eval`` plans (``render.dense_views``, ``baselines.*``, the dataset plan): their images are read
from ``{results}/relight/{run}/{obj}`` and the ``baselines.external`` folders."""

from __future__ import annotations

import argparse

from frng.plan import config as frng_config
from frng.typedconfig import typed

# The config keys this stage reads (frng.plan.digests: its rule's digest): captions (tier), compositing
# (eval.background), the runs' images for figures (frng/report/baseline_tables.py)
CONFIG_READS = ("@plan", "tier", "eval", "render.dense_views", "baselines", "benchmarks")


def configure(parser: argparse.ArgumentParser) -> None:
    frng_config.add_config_argument(parser)
    parser.add_argument(
        "--metrics", help="folder of baselines_per_image.csv / baselines_timing.csv (default {results}/metrics)"
    )
    parser.add_argument("--tables", help="tables folder (default {results}/tables)")
    parser.add_argument("--figures", help="figures folder (default {results}/figures/baselines)")
    parser.add_argument("--no-figures", action="store_true", help="write the tables only")


def loader(results, runs):
    """load(run, obj, light, view) for :func:`frng.report.baseline_tables.comparison_figure`: the ground truth (run
    None: relighting targets, or the novel-view ground truth for a light that is the object's baseline input light)
    or the run's image (None where it cannot be read)."""
    from pathlib import Path

    from frng import io
    from frng.baselines.scoring import read_prediction
    from frng.plan.layout import Layout, ObjectFolder

    by_name = {r.run: r for r in runs}
    L = Layout(results)

    def gt_path(oid, light, view):
        p = Path(L.object_image(oid, "targets", light, view))
        if p.exists():
            return p
        return Path(ObjectFolder(L.baseline_views_dir(oid)).image("targets", light, view))

    def load(run, oid, light, view):
        gt = io.read_rgba(gt_path(oid, light, view), require_alpha=True)
        if run is None:
            return gt
        if run not in by_name:
            return None
        return read_prediction(Path(results), by_name[run], oid, light, view, gt)

    return load


def run(args: argparse.Namespace) -> int:
    from pathlib import Path

    from frng import metrics as M
    from frng.baselines.scoring import planned
    from frng.plan.layout import Layout
    from frng.report import baseline_tables as BT

    config = typed(frng_config.load(args.config))
    L = Layout(config.results)
    metrics = Path(args.metrics or L.metrics_dir())
    per_image, timing = metrics / "baselines_per_image.csv", metrics / "baselines_timing.csv"
    for p in (per_image, timing):
        if not p.exists():
            print(f"frng baseline-tables: error: {p}: missing; run `frng baseline-eval` first")
            return 2
    out = BT.write_tables(per_image, timing, Path(args.tables or L.tables_dir()), config.tier, config.eval.background)
    for name, paths in out.items():
        print(f"{name}: {paths['md']}")
        print(paths["md"].read_text())
    if args.no_figures:
        return 0
    df = M.read_csv(per_image)
    load = loader(config.results, planned(config))
    figs = Path(args.figures or L.figure("baselines"))
    for name, task, runs, ref in (
        ("vs_dense", "relight", BT.dense_runs(df), BT.FRNG),
        ("vs_image_based", "relight", BT.image_runs(df), BT.FRNG),
        ("views_nvs", "nvs", BT.nvs_runs(df), BT.FRNG_NVS),
    ):
        lay = BT.comparison_figure(
            df, task, runs, ref, load, figs / f"{name}.png", f"{name} ({task})", config.eval.background
        )
        print(f"{name} figure: {lay['path'] if lay else 'nothing to show'}")
    return 0
