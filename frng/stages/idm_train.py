"""Stage ``frng idm-train`` (rule ``idm_train``): train the learned IDM on the training split's G-buffers, then
freeze it.

The training step, the cue cache and the outputs: :mod:`frng.priors.idm_train`; the loop:
:func:`frng.training.fit`.
"""

from __future__ import annotations

import argparse

from frng.priors.idm_train import train
from frng.stages._priors import configure_training, run_training


def configure(parser: argparse.ArgumentParser) -> None:
    configure_training(parser, "idm", "idm.train.steps")


def train_sections(config, objects, out, steps=None):
    """:func:`frng.priors.idm_train.train` handed the sections it reads of the typed config."""
    b = config.backbone
    return train(
        config.idm, config.model.patch_size, b.near, b.far, config.device, config.model_seed, objects, out, steps=steps
    )


def run(args: argparse.Namespace) -> int:
    return run_training(args, "idm-train", "idm", train_sections, with_targets=False)
