"""Applications: what a user runs to make, look at or use a relightable asset, built on the models and the rendering
core; the pipeline's stages (:mod:`frng.stages`) and the user's commands (:mod:`frng.commands`) are thin
wrappers around them. None imports a trainer
(:mod:`frng.training`).

- :mod:`frng.apps.relight`       relight one held-out object with every F-RNG run and the backbone, timed (``frng relight``)
- :mod:`frng.apps.capture`       your own photos in, views on the training rig out (``frng reconstruct``'s first half;
  its helpers :mod:`~frng.apps.camera_formats`, :mod:`~frng.apps.capture_frame`, :mod:`~frng.apps.masks`,
  :mod:`~frng.apps.sfm`)
- :mod:`frng.apps.reconstruct`   a prepared capture -> a relightable asset folder (``frng reconstruct``)
- :mod:`frng.apps.capture_measure`  ``frng reconstruct --measure``: the capture path against ``frng relight``
- :mod:`frng.apps.asset`         the relightable asset folder: writing, reading, rendering it without the model
- :mod:`frng.apps.render_asset`  an asset under any env map: views, turntable, video (``frng render-asset``)
- :mod:`frng.apps.view`          the interactive relighting viewer in the browser (``frng view``, viser); what it
  shows (maps, cameras, frames, a test object's images): :mod:`frng.apps.view_scene`
"""
