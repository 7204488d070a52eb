"""Snakemake's command line for the SLURM tests, with the slurm executor's status polls at most POLL_CAP_S apart.

snakemake-executor-plugin-slurm 2.6 adds 10 s to the wait after every poll that sees no job finish (up to 180 s;
hard-coded, not a setting): right for hours-long jobs, but on the test cluster a 40 s job was noticed ~30 s late and
the smoke tier's chain of such jobs waited minutes in sleeps. This launcher caps the wait and otherwise is the
``snakemake`` entry point (jobs inside SLURM run ``python -m snakemake`` as usual). Real clusters use the plugin as is.
"""

from __future__ import annotations

import sys

import snakemake_executor_plugin_slurm as slurm
from snakemake.cli import main

POLL_CAP_S = 1.0

_interval = slurm.Executor.next_seconds_between_status_checks  # the base class's property
slurm.Executor.next_seconds_between_status_checks = property(
    lambda self: min(_interval.fget(self), POLL_CAP_S), _interval.fset
)

if __name__ == "__main__":
    sys.exit(main())
