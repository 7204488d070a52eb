"""Stage ``frng idm-train`` (rule ``idm_train``): train the learned IDM on the training split's G-buffers, then
freeze it.

The training step, the cue cache and the outputs: :mod:`frng.training.idm`; the loop:
:func:`frng.training.loop.fit`.
"""

from __future__ import annotations

import argparse

from frng.stages._priors import configure_training, run_training
from frng.training.idm import train

# The config keys this stage reads (frng.plan.digests: its rule's digest): the training split, the learned IDM's
# architecture + idm.train, near/far, patch size, the models' seed, device (frng/training/idm.py); not idm.kind
# and the diffusion-renderer IDM's settings (frng/priors/__init__.py), which the learned IDM does not read
CONFIG_READS = (
    "@plan",
    "train_seed",
    "device",
    "idm",
    "!idm.kind",
    "!idm.diffusion_renderer_dir",
    "!idm.normal_space",
    "!idm.depth_invert",
    "model.patch_size",
    "backbone.near",
    "backbone.far",
)


def configure(parser: argparse.ArgumentParser) -> None:
    configure_training(parser, "idm", "idm.train.steps")


def train_sections(config, objects, out, steps=None):
    """:func:`frng.training.idm.train` handed the sections it reads of the typed config."""
    b = config.backbone
    return train(
        config.idm, config.model.patch_size, b.near, b.far, config.device, config.model_seed, objects, out, steps=steps
    )


def run(args: argparse.Namespace) -> int:
    return run_training(args, "idm-train", "idm", train_sections, with_targets=False)
