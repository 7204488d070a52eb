"""The report: the paper's tables and figures, drawn from the results folder.

- :mod:`.tables`         how a table is written: CSV + Markdown + LaTeX booktabs, best value per column marked
- :mod:`.figures`        how a figure is drawn: image grids, saliency overlays, loss curves (from arrays)
- :mod:`.paper_tables`   which tables the paper has, from the per-image metrics and timings (stage ``frng tables``)
- :mod:`.ladder`         the quality ladder: where the dB go, and the light-sensitivity rows
- :mod:`.runs`           the runs' per-image rows as tables read them: training seeds, means, paired differences
- :mod:`.paper_figures`  which figures the paper has, from the relit images (stage ``frng figures``)

The stages that write them: :mod:`frng.stages.tables`, :mod:`frng.stages.figures`.
"""
