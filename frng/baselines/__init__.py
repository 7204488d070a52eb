"""The comparisons of the paper's Tables 2 and 3 and its views table (supplementary ``tab:num_input``).

- :mod:`frng.baselines.plan`: torch-free planning (the ``baselines`` config section, which test objects the
  per-scene baselines run on, the dense views and their spread subsets, the run names);
- per-scene models fitted on dense views of one object, on the project's rasterizer and shading (``3dgs``, ``gsir``;
  one spec each in :mod:`frng.baselines.registry`, which the plan, the fit job, the scoring and the tables read);
- the image-based baseline (each target view's own photo under the input light, decomposed by the IDM and re-shaded);
- other methods' outputs read from files (``baselines.external``).

Every baseline writes what an F-RNG run writes (:class:`frng.plan.layout.RelightFolder`: ``run.json`` and
``{light}/{view}.exr``) so one scorer reads them all.
"""
