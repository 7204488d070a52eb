"""Random state: seeding a run (:func:`seed_everything`) and every random state a training step may draw from,
captured and restored for checkpoints (:func:`rng_state`, :func:`set_rng_state`) as the plain data a safe load
accepts (:func:`plain`, :func:`unplain`)."""

from __future__ import annotations

import random

import numpy as np
import torch

from frng.device import deterministic_kernels, training_threads


def seed_everything(seed: int, device: torch.device | str | None = None) -> None:
    """Python / numpy / torch seeds from ``seed``, the thread count fixed (:func:`frng.device.training_threads`) and,
    training on a CPU (``device`` cpu or None), torch's deterministic kernels on
    (:func:`frng.device.deterministic_kernels`)."""
    training_threads()
    deterministic_kernels(device)
    random.seed(seed)
    np.random.seed(seed % (2**32))
    torch.manual_seed(seed)


def _rng_get(r):
    if isinstance(r, random.Random):
        return r.getstate()
    if isinstance(r, torch.Generator):
        return r.get_state()
    if isinstance(r, np.random.Generator):
        return r.bit_generator.state
    if isinstance(r, np.random.RandomState):
        return r.get_state()
    raise TypeError(f"fit: cannot checkpoint the state of a {type(r).__name__}")


def _rng_set(r, state) -> None:
    if isinstance(r, random.Random):
        r.setstate(state)
    elif isinstance(r, torch.Generator):
        r.set_state(state)
    elif isinstance(r, np.random.Generator):
        r.bit_generator.state = state
    else:
        r.set_state(state)


def plain(x):
    """Random states in the plain data a safe load accepts (:func:`frng.io.load_torch`): numpy arrays (numpy's
    MT19937 key) become ``{"__ndarray__": list, "dtype": str}``."""
    if isinstance(x, np.ndarray):
        return {"__ndarray__": x.tolist(), "dtype": str(x.dtype)}
    if isinstance(x, np.generic):
        return x.item()
    if isinstance(x, dict):
        return {k: plain(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return type(x)(plain(v) for v in x)
    return x


def unplain(x):
    """The inverse of :func:`plain`."""
    if isinstance(x, dict):
        if "__ndarray__" in x:
            return np.asarray(x["__ndarray__"], dtype=x["dtype"])
        return {k: unplain(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return type(x)(unplain(v) for v in x)
    return x


def rng_state(device: torch.device | str | None = None, rngs: dict | None = None) -> dict:
    """Every random state a training step may draw from: python's, numpy's and torch's global generators, the
    CUDA generator of ``device`` (when it is a GPU), and the trainer's own generators ``rngs`` (name -> a
    ``random.Random``, ``torch.Generator`` or numpy generator)."""
    state = {
        "python": random.getstate(),
        "numpy": plain(np.random.get_state()),
        "torch": torch.get_rng_state(),
        "trainer": {k: plain(_rng_get(r)) for k, r in (rngs or {}).items()},
    }
    if device is not None and torch.device(device).type == "cuda":
        state["cuda"] = torch.cuda.get_rng_state(torch.device(device))
    return state


def set_rng_state(state: dict, device: torch.device | str | None = None, rngs: dict | None = None) -> None:
    """Restore what :func:`rng_state` captured."""
    random.setstate(state["python"])
    np.random.set_state(unplain(state["numpy"]))
    torch.set_rng_state(state["torch"])
    if "cuda" in state and device is not None and torch.device(device).type == "cuda":
        torch.cuda.set_rng_state(state["cuda"], torch.device(device))
    for k, r in (rngs or {}).items():
        _rng_set(r, unplain(state["trainer"][k]))
