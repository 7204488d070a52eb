"""The trainers: each owns its training section and writes a model file that inference loads without them.

- :mod:`frng.training.loop`          the one training loop (:func:`~frng.training.loop.fit`): resume, schedule, clipping,
  checkpoints, loss log; device and bf16 helpers
- :mod:`frng.training.backbone`      the frozen LRM backbone (stage ``frng backbone-train``)
- :mod:`frng.training.idm`           the learned intrinsic-decomposition model (stage ``frng idm-train``)
- :mod:`frng.training.frng_trainer`  one F-RNG variant: L_2, L_per, L_ind, the step (stage ``frng train``)
- :mod:`frng.training.distributed`   data-parallel training over torchrun ranks (one GPU each)

Models (:mod:`frng.model`, :mod:`frng.priors`) and the applications (:mod:`frng.apps`) import no trainer; a trainer
imports the planning (:mod:`frng.plan`) to know what a variant is and where its outputs go.
"""
