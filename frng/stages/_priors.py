"""What the two priors' training stages share (:mod:`.backbone_train`, :mod:`.idm_train`); not a stage itself."""

from __future__ import annotations

import argparse
import time
from collections.abc import Callable
from pathlib import Path

from frng.plan import config as frng_config
from frng.plan.layout import Layout
from frng.typedconfig import typed


def configure_training(parser: argparse.ArgumentParser, folder: str, steps_key: str) -> None:
    """Arguments of a priors training stage: ``--config``, ``--out`` (default ``{results}/<folder>``), ``--steps``."""
    frng_config.add_config_argument(parser)
    parser.add_argument("--out", help=f"output folder (default {{results}}/{folder})")
    parser.add_argument("--steps", type=int, help=f"override {steps_key}")


def run_training(args: argparse.Namespace, stage: str, folder: str, train: Callable, **load_kw) -> int:
    """Load the config and the training split (:func:`frng.priors.dataset.load_split` with ``load_kw``), train
    with ``train(config, objects, out, steps=...)`` (the stage's adapter: it hands the trainer the sections it
    reads) and say where the model went."""
    from frng.plan import catalog
    from frng.priors.dataset import load_split

    config = typed(frng_config.load(args.config))
    out = Path(args.out or getattr(Layout(config.results), f"{folder}_dir")())
    t0 = time.time()
    objects = load_split(config.results, catalog.plan(config).split("train"), **load_kw)
    print(f"{stage}: {len(objects)} training objects loaded in {time.time() - t0:.1f}s")
    print(f"{stage}: wrote {train(config, objects, out, steps=args.steps)}")
    return 0
