"""Stage ``frng relight --object OBJ [--group G]`` (rules ``relight`` and ``relight_seed``, one job per test object
and relighting group): relight one held-out object with every F-RNG run and with the backbone, timed side by side,
or with the runs of one group only (``main``: the models' seed and the backbone; a training seed: its
``{variant}@s{seed}`` runs); prints the timing.

What one job does, the runs, the outputs and the timing file: :mod:`frng.apps.relight`.
"""

from __future__ import annotations

import argparse

from frng.stages import _relight

# The config keys this stage reads (frng.plan.digests: its rule's digest): the dataset plan (the split check) and what
# relighting reads (frng/apps/relight.py, group @relight). The rule `relight` relights the main group only
# (frng.plan.variants.MAIN_GROUP: the models' seed and the backbone), whose runs do not depend on the other training
# seeds: it leaves train.seeds out, so that `make seeds` (train.seeds [0] -> [0, 1]) adds the relight_seed jobs
# without rerunning the first seed's relight jobs (their outputs were identical)
CONFIG_READS = ("@plan", "@relight", "!train.seeds")


def configure(parser: argparse.ArgumentParser) -> None:
    _relight.configure(parser)


def run(args: argparse.Namespace) -> int:
    return _relight.run(args)
