"""Stage ``frng relight-seed --object OBJ --group SEED`` (rule ``relight_seed``, one job per test object and
training seed other than the models'): exactly ``frng relight --group SEED`` (:mod:`frng.stages.relight`,
:mod:`frng.apps.relight`), the ``{variant}@s{SEED}`` runs of one held-out object, no timing. A stage of its own only so
that each rule runs the stage named after it."""

from __future__ import annotations

import argparse

from frng.stages import _relight

# The config keys this stage reads (frng.plan.digests: its rule's digest): what `frng relight` reads, the training
# seeds included (the other seeds' runs)
CONFIG_READS = ("@plan", "@relight")


def configure(parser: argparse.ArgumentParser) -> None:
    _relight.configure(parser)


def run(args: argparse.Namespace) -> int:
    return _relight.run(args)
