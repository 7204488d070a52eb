"""Planning, torch-free: what the pipeline will make and where, decided from the config alone (fast enough for the
Snakefile and dry runs).

- :mod:`frng.plan.sections`  typed config sections (a leaf: imports no frng module)
- :mod:`frng.plan.config`    loading, validating and recording the config
- :mod:`frng.plan.digests`   which config keys each rule reads (from the stages' declarations) and their digests
- :mod:`frng.plan.catalog`   the dataset plan: objects, splits, materials, lights, seeds
- :mod:`frng.plan.curate_jobs`     what the workflow needs of the plan for one curation job (runtime, record, inputs)
- :mod:`frng.plan.dataset_config`  the dataset's config sections (envmaps, render, objects) and CatalogError
- :mod:`frng.plan.object_files`    the object files the plan draws from (pybullet_data, Objaverse, LIBERO) and
                                  what a mesh file carries
- :mod:`frng.plan.variants`  what gets trained and relit: variants, seeds, runs, groups
- :mod:`frng.plan.layout`    where every artefact lives in the results folder
- :mod:`frng.plan.batches`   batches of objects for the jobs
"""
