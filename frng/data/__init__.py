"""The dataset: plan (catalog, camera rig, env-map split), curation stages, contact sheets, reader.

- :mod:`frng.data.catalog`  -- what gets rendered (objects, splits, materials, lights, seeds); no bpy, fast
- :mod:`frng.data.rig`      -- camera rig: 6 input views (+ extras) and random target views
- :mod:`frng.data.envmaps`  -- stage ``frng envmaps``: bundled HDRIs + baked skies, rotated, split
- :mod:`frng.data.curate`   -- stage ``frng curate``: one Blender process renders one object
- :mod:`frng.data.preview`  -- stage ``frng dataset preview``: PNG contact sheets
- :mod:`frng.data.dataset`  -- reader every later stage uses
"""
