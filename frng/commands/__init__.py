"""The commands a user runs by hand that no Snakemake rule runs: ``frng reconstruct``, ``render-asset``, ``view``,
``export-asset``, ``export``, ``export-image-inputs``, ``results-page`` and ``config`` (:data:`frng.cli.USER_COMMANDS`).

A command is built as a stage is (:mod:`frng.stages`): arguments and orchestration around the libraries, two
functions ``configure(parser)`` and ``run(args)``, no classes. It declares no ``CONFIG_READS`` (no rule, no config
digest). What the pipeline's rules run lives in :mod:`frng.stages`, one module per rule; the benchmarks and
diagnostics in :mod:`frng.diagnostics`.
"""
