"""F-RNG: Feed-Forward Relightable Neural Gaussians -- a reproducible pipeline.

Stages are CLI subcommands (``frng --help``); the Snakemake workflow in ``workflow/`` chains them.
"""

__version__ = "0.1.0"
