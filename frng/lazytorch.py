"""``torch``, imported on first use: for the modules that mix numpy helpers with torch ones (:mod:`frng.camera`,
:mod:`frng.render.envmap`) and are also imported by torch-free stages.

A curation job (one Blender process per object, ~140 per default-tier run) reads env maps and builds its camera
rig with those modules' numpy halves only; importing torch cost each job ~2.5 s of its ~12 s (3 min of the
default tier's wall time on 2 cores). ``from frng.lazytorch import torch`` gives a stand-in whose first attribute
access imports the real module; ``sys.modules`` is not touched, so every other ``import torch`` is the usual
one. A module using it must not touch ``torch`` at import time (no ``dtype=torch.float32`` defaults: ``None``
resolved inside the function), which tests/test_lazy_imports.py checks by importing the torch-free stages in a
fresh interpreter.
"""

from __future__ import annotations


class _LazyTorch:
    __slots__ = ()

    def __getattr__(self, name: str):
        import torch

        return getattr(torch, name)

    def __repr__(self) -> str:
        return "<torch, imported on first use (frng.lazytorch)>"


torch = _LazyTorch()
