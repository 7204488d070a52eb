"""The dataset: camera rig, env maps, curation, contact sheets, reader. What gets rendered (objects, splits,
materials, lights, seeds) is the torch-free plan, :mod:`frng.plan.catalog`.

- :mod:`frng.data.rig`      -- camera rig: 6 input views (+ extras) and random target views
- :mod:`frng.data.envmaps`  -- bundled HDRIs + baked skies, rotated, split (stage :mod:`frng.stages.envmaps`)
- :mod:`frng.data.curate`   -- one Blender process renders one object (stage :mod:`frng.stages.curate`)
- :mod:`frng.data.preview`  -- PNG contact sheets (stage :mod:`frng.stages.dataset_preview`)
- :mod:`frng.data.dataset`  -- reader every later stage uses
"""
