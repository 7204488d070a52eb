"""The pipeline's stages: one module per Snakemake rule, named after it (``rules/*.smk``).

A stage is what a rule runs, the ``frng <stage>`` subcommand (:data:`frng.cli.STAGES`): it holds only argument
parsing and orchestration, two functions::

    def configure(parser: argparse.ArgumentParser) -> None   # add arguments (or sub-subcommands)
    def run(args: argparse.Namespace) -> int | None           # do the work

and, when a rule runs it, one declaration: the config sections and keys ``run`` reads (libraries included), whence
the rule's config digest follows (:mod:`frng.plan.digests`: read from the source, so planning imports no stage)::

    CONFIG_READS = ("@plan", "train", "!train.seeds", ...)

``run`` reads the config, loops over objects, calls the libraries (:mod:`frng.data`, :mod:`frng.priors`,
:mod:`frng.model`, :mod:`frng.render`, :mod:`frng.report`, ...) and writes the outputs; the algorithms live in the
libraries. ``tests/test_stages.py`` maps the rules to these modules one to one: every rule that runs ``frng <stage>`` runs the
module named after it, and every module here is run by exactly one rule. Modules whose name starts with ``_`` are
helpers shared by stages, not stages: :mod:`._priors` (the two priors' trainings) and :mod:`._relight` (the three
relighting rules). What a user runs by hand with no rule lives in :mod:`frng.commands`; the benchmarks and
diagnostics (``frng bench``) in :mod:`frng.diagnostics`.
"""
