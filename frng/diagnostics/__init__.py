"""Benchmarks and diagnostics run by hand, never by the workflow: ``frng bench <name>`` (:mod:`.bench`, its table
:data:`.bench.BENCHES`; ``make bench``).

Not to be confused with :mod:`frng.benchmarks`, the readers and writers of the PUBLIC relighting benchmarks
(TensoIR, ORB, OWL, NeRF-synthetic): this package measures the project's own code and models (timings of the
rasterizer, shading, relighting and training; held-out quality of trained models and backbones; the curated images'
noise floor).

Each benchmark is a module ``bench_<name>.py`` with the stages' two functions, ``configure(parser)`` and
``run(args)`` (:mod:`frng.stages`); :mod:`._heldout` is what ``frng bench heldout`` and ``frng bench backbone``
share. No rule runs them, so they declare no ``CONFIG_READS`` and have no config digest.
"""
