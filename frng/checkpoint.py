"""Checkpoints of a training run and when one is resumed (:func:`frng.training.loop.fit`).

``{out}/checkpoint.pt`` is written atomically (:func:`save`) every ``checkpoint_every`` steps and holds the model,
optimiser, step, every random state (python, numpy, torch, CUDA, the trainer's sampling generators; per rank,
:func:`frng.seeding.rng_state`), the full loss history, the elapsed time and the digest
(:func:`frng.hashing.config_digest`) of the trainer's :func:`fingerprint`: architecture, training config (but
``checkpoint_every``), steps, seed, world size and a digest of the training data
(:func:`frng.hashing.data_digest`) or of the frozen models it reads. A rerun continues the checkpoint only when its
digest matches and it is unfinished (:func:`load_resumable`); a changed config starts from step 0, and so does a
run whose checkpoint is finished (``step == total``, written after the model): the model was asked for again
(``snakemake -f`` deletes ``model.pt`` but not the checkpoint), so it is trained again. A killed run loses at most
``checkpoint_every`` steps and, on a CPU, ends bit-identical to an uninterrupted one, its ``loss.csv`` covering
steps 1..N.
"""

from __future__ import annotations

import dataclasses
import os
from pathlib import Path

from frng import io
from frng.plan.layout import TrainingFolder
from frng.seeding import plain

CHECKPOINT_FORMAT = 2  # checkpoints of another format (or none) are never resumed


def fingerprint_config(tcfg) -> dict:
    """A training-config dataclass as a fingerprint entry: every field but ``checkpoint_every`` (how often a run
    is saved does not change what it trains, so changing it keeps a run resumable)."""
    return {k: v for k, v in dataclasses.asdict(tcfg).items() if k != "checkpoint_every"}


def fingerprint(arch: dict, tcfg, steps: int, seed: int, **extra) -> dict:
    """What a run's checkpoint must agree on to be continued (:func:`frng.hashing.config_digest` of it): the
    architecture, the training config (:func:`fingerprint_config`), the steps, the seed and the trainer's ``extra``
    entries (its data's :func:`frng.hashing.data_digest`, frozen models' hashes, ...)."""
    return {"arch": arch, "train": fingerprint_config(tcfg), "steps": steps, "seed": seed, **extra}


def save(
    path: str | os.PathLike,
    *,
    step: int,
    total: int,
    digest: str,
    fingerprint: dict,
    model: dict,
    optimizer: dict,
    rng: list,
    history: list[dict],
    elapsed: float,
) -> None:
    """Write a checkpoint atomically: plain data only (tensors, numbers, strings, lists, dicts), so that it is
    loaded with ``weights_only`` (:func:`load_resumable`). ``model`` / ``optimizer``: their state dicts; ``rng``:
    every rank's :func:`frng.seeding.rng_state`; ``history``: the loss log's rows."""
    io.save_torch(
        {
            "format": CHECKPOINT_FORMAT,
            "step": step,
            "total": total,
            "digest": digest,
            "fingerprint": plain(fingerprint),
            "model": model,
            "optimizer": optimizer,
            "rng": rng,
            "history": plain(history),
            "elapsed": float(elapsed),
        },
        path,
    )


def load_resumable(out: str | os.PathLike, digest: str, total: int) -> tuple[dict | None, str | None]:
    """The checkpoint in ``out`` when a run may continue it, else None; and why (one line; None: no checkpoint).

    A checkpoint is continued only when it is of this format, its digest equals ``digest`` (same architecture,
    training config, steps, seed, data and world size) and it is unfinished (``step < total``). A finished one
    (``step == total``: the run that wrote it went on to save its model) means the model was asked for again --
    ``snakemake -f``/``-R`` deletes the model but not the checkpoint, or the command was rerun by hand -- and a
    run asked for again trains again, from step 0."""
    path = Path(TrainingFolder(out).checkpoint())
    if not path.exists():
        return None, None
    try:
        state = io.load_torch(path, "checkpoint")  # weights_only: a crafted checkpoint.pt runs nothing
    except Exception as e:  # noqa: BLE001 -- an unreadable checkpoint is not resumable, whatever the cause
        return None, f"{e}; training from step 0"
    if not isinstance(state, dict) or state.get("format") != CHECKPOINT_FORMAT:
        return None, f"{path} predates the training-config digest; training from step 0"
    if state.get("digest") != digest:
        return None, f"{path} was written with another training config or data; training from step 0"
    if int(state["step"]) >= total:
        return None, f"{path} is a finished run ({state['step']} of {total} steps); training again from step 0"
    return state, f"resuming {path} at step {state['step']} of {total}"
