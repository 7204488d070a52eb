"""Applications: what a user runs to make, look at or use a relightable asset, built on the models and the rendering
core; the pipeline's stages (:mod:`frng.stages`) are thin wrappers around them. None imports a trainer
(:mod:`frng.training`).

- :mod:`frng.apps.relight`       relight one held-out object with every F-RNG run and the backbone, timed (``frng relight``)
- :mod:`frng.apps.capture`       your own photos in, a relightable asset out (``frng reconstruct``)
- :mod:`frng.apps.asset`         the relightable asset folder: writing, reading, rendering it without the model
- :mod:`frng.apps.render_asset`  an asset under any env map: views, turntable, video (``frng render-asset``)
- :mod:`frng.apps.view`          the interactive relighting viewer in the browser (``frng view``, viser)
"""
