"""Stage ``frng relight-benchmark --object ID`` (rule ``relight_benchmark``, one job per imported benchmark
object): exactly ``frng relight`` (:mod:`frng.stages.relight`, :mod:`frng.apps.relight`) on an object that
``frng import`` wrote -- every F-RNG run and the backbone under the benchmark's target lights at its target views,
timed side by side. A stage of its own only so that each rule runs the stage named after it."""

from __future__ import annotations

import argparse

from frng.stages import _relight

# The config keys this stage reads (frng.plan.digests: its rule's digest): what relighting reads (frng/apps/relight.py) and
# the seed
CONFIG_READS = ("@relight", "seed")


def configure(parser: argparse.ArgumentParser) -> None:
    _relight.configure(parser)


def run(args: argparse.Namespace) -> int:
    return _relight.run(args)
