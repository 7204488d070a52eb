"""Stage ``frng backbone-train`` (rule ``backbone_train``): train the RelitLRM-style backbone on the training split,
then freeze it.

The training step, the loss and the outputs (``model.pt``, ``checkpoint.pt``, ``loss.csv/png``, ``train.json``):
:mod:`frng.training.backbone`; the loop: :func:`frng.training.loop.fit`.
"""

from __future__ import annotations

import argparse

from frng.stages._priors import configure_training, run_training
from frng.training.backbone import train

# The config keys this stage reads (frng.plan.digests: its rule's digest): the training split, architecture +
# backbone.train, patch size, the models' seed (frng.training.loop.train_seed: train_seed, else seed), device
# (frng/training/backbone.py)
CONFIG_READS = ("@plan", "train_seed", "device", "backbone", "!backbone.cache_extra_lights", "model.patch_size")


def configure(parser: argparse.ArgumentParser) -> None:
    configure_training(parser, "backbone", "backbone.train.steps")


def train_sections(config, objects, out, steps=None):
    """:func:`frng.training.backbone.train` handed the sections it reads of the typed config."""
    return train(config.backbone, config.model.patch_size, config.device, config.model_seed, objects, out, steps=steps)


def run(args: argparse.Namespace) -> int:
    return run_training(args, "backbone-train", "backbone", train_sections)
