"""THE training loop of the three training stages (``frng backbone-train``, ``frng idm-train``, ``frng train``):
:func:`fit` runs a :class:`Trainer` -- the trainer's model, optimiser and three named hooks (one step, saving the
model, ``train.json``) -- and owns the rest: resume, LR schedule (:func:`cosine_lr`), clipping with the non-finite-step
skip, the loss log, progress bar, checkpoints and ``train.json``. Data parallelism plugs in as :class:`FitHooks`
(:func:`frng.training.distributed.fit_hooks`).

What the loop uses lives beside it, one module per concept: :mod:`frng.device` (device, bf16, threads),
:mod:`frng.seeding` (seeds, random states), :mod:`frng.hashing` (file, data and fingerprint digests),
:mod:`frng.losslog` (``loss.csv`` / ``loss.png``), :mod:`frng.checkpoint` (what a checkpoint holds, when it is
resumed).

A finished run writes the final model file (``model.pt``) with the trainer's ``save_model``: ``{"kind",
"config", "state_dict", "steps", "sha256"...}``; the hash is computed over the file's bytes by
:func:`frng.hashing.file_sha256` and is what caches record to detect a stale cache.
"""

from __future__ import annotations

import os
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch
from tqdm import tqdm

from frng import checkpoint, io
from frng.hashing import config_digest
from frng.losslog import LossLog
from frng.plan.layout import TrainingFolder
from frng.seeding import rng_state, set_rng_state

PROGRESS_LOG_S = 30.0  # seconds between progress lines when stderr is a log file


def cosine_lr(step: int, total: int, peak: float, warmup: int) -> float:
    """Linear warm-up to ``peak`` then cosine decay to 10% of it."""
    if step < warmup:
        return peak * (step + 1) / warmup
    t = (step - warmup) / max(1, total - warmup)
    return peak * (0.1 + 0.9 * 0.5 * (1.0 + np.cos(np.pi * min(1.0, t))))


class Timer:
    """Wall time of a run, carried across resumes (the checkpoint stores the elapsed seconds)."""

    def __init__(self, offset: float = 0.0):
        self.start = time.time() - offset

    def elapsed(self) -> float:
        return time.time() - self.start


def _identity(x):
    return x


def _as_list(x) -> list:
    return [x]


def _noop() -> None:
    return None


@dataclass
class FitHooks:
    """What a data-parallel trainer plugs into :func:`fit` (the defaults are a single process); see
    :func:`frng.training.distributed.fit_hooks`. ``reduce_logs``: this rank's step logs -> the logs of the whole step
    (every rank gets them); ``gather``: a picklable object of this rank -> the list of every rank's, in rank
    order (a collective: every rank calls it); ``barrier``: wait for every rank. Rank 0 writes every file."""

    rank: int = 0
    world_size: int = 1
    reduce_logs: Callable[[dict], dict] = _identity
    gather: Callable[[Any], list] = _as_list
    barrier: Callable[[], None] = _noop

    @property
    def is_main(self) -> bool:
        return self.rank == 0


@dataclass
class FitRun:
    """What :func:`fit` hands the trainer's ``summary`` for ``train.json``."""

    steps: int  # total steps of the run
    start: int  # the step this call started from (> 0: resumed)
    wall_s: float  # wall time over every call of the run (carried across resumes)
    step_times: list[float] = field(default_factory=list)  # this call's seconds per step
    skipped: int = 0  # steps of this call whose gradient norm was not finite (no update)

    @property
    def step_s_mean(self) -> float:
        return sum(self.step_times) / max(1, len(self.step_times))


@dataclass
class Trainer:
    """What a trainer hands :func:`fit`: its model and optimiser, three named hooks, and how the run is shown (a
    small object with named hooks, as gsplat's strategies are, rather than loose callables).

    Hooks: ``step(step) -> logs`` runs one step's forward and backward passes (the gradients start at None) and
    returns the step's scalar loss terms (named in ``loss_names``; ``total`` first); ``save_model(path)`` writes
    the finished model; ``summary(run) -> dict`` is ``train.json`` (:class:`FitRun`; fit adds ``threads``).

    ``params``: the parameters whose gradient norm is clipped (default: the model's, in its order; the order fixes
    the norm's rounding); ``rngs``: the trainer's own generators (name -> ``random.Random``, ``torch.Generator`` or
    numpy generator), checkpointed with the global ones; ``device``: whose CUDA generator is checkpointed;
    ``hooks``: data parallelism (:class:`FitHooks`; ``step`` then runs the DDP-wrapped module); ``title``: the loss
    plot's; ``desc``: the progress bar's and the log lines'; ``postfix``: the loss terms on the bar."""

    model: torch.nn.Module
    optimizer: torch.optim.Optimizer
    step: Callable[[int], dict[str, float]]
    save_model: Callable[[Path], None]
    summary: Callable[[FitRun], dict]
    loss_names: list[str]
    title: str
    desc: str
    params: list[torch.nn.Parameter] | None = None
    postfix: tuple[str, ...] = ("total",)
    rngs: dict | None = None
    device: torch.device | str | None = None
    hooks: FitHooks = field(default_factory=FitHooks)


def run_summary(run: FitRun, device, objects: list, bf16: bool, model: torch.nn.Module) -> dict:
    """``train.json`` of a priors trainer: steps, wall time, device, objects, bf16, parameters."""
    return {
        "steps": run.steps,
        "wall_s": round(run.wall_s, 1),
        "device": str(device),
        "objects": len(objects),
        "bf16": bf16,
        "parameters": sum(p.numel() for p in model.parameters()),
    }


def fit(
    trainer: Trainer,
    tcfg,
    *,
    out: str | os.PathLike,
    total: int,
    fingerprint: dict,
    stop_after: int | None = None,
) -> Path:
    """Run (or resume) ``trainer``'s run of ``total`` steps in ``out``; returns ``out/model.pt`` (the checkpoint's
    path when stopped by ``stop_after``).

    The trainer builds the model, optimiser and data, seeds, and hands over a :class:`Trainer` and its training
    config ``tcfg`` (any object with ``lr``, ``warmup``, ``grad_clip`` and ``checkpoint_every``). fit owns the
    rest:

    - resume: :func:`frng.checkpoint.load_resumable` with the digest of ``fingerprint`` (+ world size); a resumed
      run restores the model, optimiser, every random state (:func:`frng.seeding.rng_state`: global generators,
      the trainer's ``rngs``, per rank), the loss history and the elapsed time, so a killed and resumed run ends
      where an uninterrupted one does (bit-exact on a CPU) and its ``loss.csv`` covers every step. A checkpoint
      that is not resumed is deleted (it would describe another run);
    - the learning rate of step s: :func:`cosine_lr` (warm-up + cosine), times the group's ``lr_mult`` if any;
    - clipping the gradient norm of the trainer's ``params`` to ``grad_clip``, and no update on a step whose norm
      is not finite (the step is still logged; the bar says so);
    - ``loss.csv`` / ``loss.png`` (:class:`frng.losslog.LossLog`, rank 0), the progress bar (rank 0);
    - atomic checkpoints (:func:`frng.checkpoint.save`) every ``checkpoint_every`` steps, at ``stop_after``
      (tests of resumption), and once the model is saved a final one (``step == total``, the marker of a
      finished run);
    - at the end (rank 0): ``trainer.save_model(TrainingFolder(out).model())`` then ``train.json`` =
      ``trainer.summary(FitRun)``.
    """
    hooks, model, optimizer = trainer.hooks, trainer.model, trainer.optimizer
    device, rngs, desc = trainer.device, trainer.rngs, trainer.desc
    params = list(model.parameters()) if trainer.params is None else trainer.params
    lr, warmup, grad_clip = tcfg.lr, tcfg.warmup, tcfg.grad_clip
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    files = TrainingFolder(out)
    ckpt_path = Path(files.checkpoint())
    digest = config_digest({"fingerprint": fingerprint, "world_size": hooks.world_size})
    state, why = checkpoint.load_resumable(out, digest, total)
    hooks.barrier()  # every rank has read the checkpoint before rank 0 may delete it
    if hooks.is_main and why:
        print(f"{desc}: {why}", flush=True)
        if state is None:
            ckpt_path.unlink(missing_ok=True)
    start = 0
    if state is not None:
        model.load_state_dict(state["model"])
        optimizer.load_state_dict(state["optimizer"])
        set_rng_state(state["rng"][hooks.rank], device, rngs)
        start = int(state["step"])
    log = LossLog(out, trainer.loss_names, state["history"] if state else None) if hooks.is_main else None
    timer = Timer(float(state["elapsed"]) if state else 0.0)
    run = FitRun(steps=total, start=start, wall_s=0.0)
    every = max(1, int(tcfg.checkpoint_every))

    def save_checkpoint(step: int) -> None:
        states = hooks.gather(rng_state(device, rngs))  # collective
        if hooks.is_main:
            checkpoint.save(
                ckpt_path,
                step=step,
                total=total,
                digest=digest,
                fingerprint=fingerprint,
                model=model.state_dict(),
                optimizer=optimizer.state_dict(),
                rng=states,
                history=log.rows,
                elapsed=timer.elapsed(),
            )
        hooks.barrier()

    model.train()
    # In a terminal the bar updates live; in a rule's log file (not a TTY) every PROGRESS_LOG_S seconds, so the log
    # stays a readable few lines instead of one carriage return per step.
    tty = sys.stderr.isatty()
    bar = tqdm(
        range(start, total),
        initial=start,
        total=total,
        desc=desc,
        dynamic_ncols=True,
        disable=not hooks.is_main,
        mininterval=0.1 if tty else PROGRESS_LOG_S,
        maxinterval=10.0 if tty else PROGRESS_LOG_S,  # tqdm's default 10 s would force a line every ~15 s
    )
    ran = 0
    for step in bar:
        t0 = time.time()
        lr_now = cosine_lr(step, total, lr, warmup)
        for g in optimizer.param_groups:
            g["lr"] = float(lr_now * g.get("lr_mult", 1.0))  # a python float: checkpoints hold plain data
        optimizer.zero_grad(set_to_none=True)
        logs = trainer.step(step)
        gnorm = torch.nn.utils.clip_grad_norm_(params, grad_clip)
        if torch.isfinite(gnorm):
            optimizer.step()
        else:
            run.skipped += 1
            if hooks.is_main:
                bar.write(f"{desc}: step {step + 1}: gradient norm {float(gnorm)}, no update")
        logs = hooks.reduce_logs(logs)
        run.step_times.append(time.time() - t0)
        if log:
            log.append(step + 1, timer.elapsed(), logs)
        bar.set_postfix({("loss" if k == "total" else k): f"{logs[k]:.4f}" for k in trainer.postfix}, refresh=False)
        ran += 1
        due = (step + 1) % every == 0 and step + 1 < total
        stop = stop_after is not None and ran >= stop_after and step + 1 < total
        if due or stop:
            save_checkpoint(step + 1)
        if due and log:
            log.plot(trainer.title)
        if stop:
            return ckpt_path
    bar.close()
    path = Path(files.model())
    if hooks.is_main:
        log.plot(trainer.title)
        trainer.save_model(path)
        run.wall_s = timer.elapsed()
        io.write_json(
            files.summary(), {**trainer.summary(run), "threads": torch.get_num_threads()}
        )  # the weights depend on it
    save_checkpoint(total)  # after the model: a finished checkpoint is never resumed (load_resumable)
    return path


# -- the priors' trainers (:mod:`frng.training.backbone`, :mod:`frng.training.idm`) -----------------------


def check_training_split(objects: list, stage: str) -> None:
    """A priors trainer sees training objects only, and at least one."""
    if any(o.split != "train" for o in objects):
        raise ValueError(f"{stage} must only see training objects")
    if not objects:
        raise ValueError(f"{stage}: no training objects")
