"""Training plumbing shared by the training stages (``frng backbone-train``, ``frng idm-train``, ``frng train``).

- :func:`fit` -- THE training loop of all three: resume, LR schedule, clipping with the non-finite-step skip,
  loss log, progress bar, checkpoints, ``train.json``; a trainer supplies one step function (and, for data
  parallelism, :class:`FitHooks` from :func:`frng.distributed.fit_hooks`).
- :func:`resolve_device` -- ``auto`` = CUDA when present, else CPU.
- :func:`autocast` -- bf16 autocast context (CPU AMX or CUDA) or a no-op.
- :func:`train_seed` -- the learned models' seed (``train_seed``, else ``seed``);
- :func:`seed_everything` -- python / numpy / torch seeds from it.
- :class:`LossLog` -- ``{out}/loss.csv`` (one row per step: step, elapsed_s, then named loss terms) and
  ``{out}/loss.png`` (curves, log-scale y, a moving average on top of the raw values).

Checkpoints and resume (:func:`fit`, :func:`load_resumable`): ``{out}/checkpoint.pt`` is written atomically every
``checkpoint_every`` steps and holds the model, optimiser, step, every random state (python, numpy, torch, CUDA,
the trainer's sampling generators; per rank), the full loss history, the elapsed time and the digest
(:func:`config_digest`) of the trainer's fingerprint: architecture, training config (but ``checkpoint_every``),
steps, seed, world size and a digest of the training data (:func:`data_digest`) or of the frozen models it reads.
A rerun continues the checkpoint only when its digest matches and it is unfinished; a changed config starts
from step 0, and so does a run whose checkpoint is finished (``step == total``, written after the model): the
model was asked for again (``snakemake -f`` deletes ``model.pt`` but not the checkpoint), so it is trained
again. A killed run loses at most ``checkpoint_every`` steps and, on a CPU, ends bit-identical to an
uninterrupted one, its ``loss.csv`` covering steps 1..N.

A finished run writes the final model file (``model.pt``) with the trainer's ``save_model``: ``{"kind",
"config", "state_dict", "steps", "sha256"...}``; the hash is computed over the file's bytes by :func:`file_sha256`
and is what caches record to detect a stale cache.
"""

from __future__ import annotations

import contextlib
import csv
import dataclasses
import functools
import hashlib
import json
import os
import random
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch
from tqdm import tqdm

from frng import io
from frng.layout import TrainingFolder


def resolve_device(name: str = "auto") -> torch.device:
    """``auto`` -> ``cuda`` when available, else ``cpu``; ``cuda`` without a GPU is an error."""
    if name == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    if name == "cuda" and not torch.cuda.is_available():
        raise RuntimeError("config device is 'cuda' but no CUDA device is available")
    return torch.device(name)


@functools.cache
def _cpu_has_bf16() -> bool:
    """Whether this CPU computes bf16 natively (AMX or AVX512-BF16). Without it, torch emulates bf16 matmuls and
    autocast is several times SLOWER than float32 (measured 8x on an AVX2-only AMD EPYC)."""
    try:
        flags = Path("/proc/cpuinfo").read_text()
    except OSError:
        return False
    return any(f in flags for f in ("amx_bf16", "avx512_bf16"))


def bf16_ok(device: torch.device | str) -> bool:
    """Whether bf16 autocast pays on ``device``: CUDA with bf16 support, or a CPU with native bf16 (AMX/AVX512-BF16).
    Every ``bf16`` config switch means "bf16 where the hardware has it" and goes through this test."""
    device = torch.device(device)
    if device.type == "cuda":
        return torch.cuda.is_available() and torch.cuda.is_bf16_supported()
    return device.type == "cpu" and _cpu_has_bf16()


def autocast(device: torch.device, bf16: bool):
    """bf16 autocast on ``device`` when ``bf16`` is set and :func:`bf16_ok`, else a no-op context."""
    if not (bf16 and bf16_ok(device)):
        return contextlib.nullcontext()
    return torch.autocast(device_type=device.type, dtype=torch.bfloat16)


THREADS_ENV = "FRNG_TORCH_THREADS"


def training_threads() -> int:
    """The intra-op thread count a training runs with (``train.json``'s ``threads``), fixed before any op runs.

    The weights are bit-identical between runs of the same config on the same machine for the same count (1 and
    2 threads measured, also two 2-thread runs side by side; ``tests/test_determinism.py``), but differ between
    counts: reductions and GEMMs split their sums per thread. The count is ``FRNG_TORCH_THREADS`` when set, else
    torch's (``OMP_NUM_THREADS``, which Snakemake sets to the job's threads: min(rule ``threads``, ``--cores``))."""
    n = os.environ.get(THREADS_ENV, "").strip()
    if n:
        torch.set_num_threads(int(n))
    return torch.get_num_threads()


def seed_everything(seed: int) -> None:
    """Python / numpy / torch seeds from ``seed``, and the thread count fixed (:func:`training_threads`)."""
    training_threads()
    random.seed(seed)
    np.random.seed(seed % (2**32))
    torch.manual_seed(seed)


def file_sha256(path: str | os.PathLike) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def save_torch(obj, path: str | os.PathLike) -> None:
    """``torch.save`` through a temporary file renamed into place (a killed job leaves no partial file); the same
    object gives the same bytes (:func:`frng.io.save_torch`). Read back with :func:`frng.io.load_torch`."""
    io.save_torch(obj, path)


class LossLog:
    """Loss CSV (one row per step, header written up front) and a PNG plot of all terms.

    ``rows`` is the history a resumed run continues (the checkpoint carries it, so the CSV covers every step even
    when the file itself was deleted, as Snakemake does with the outputs of a killed job); the CSV is rewritten
    from it at once."""

    def __init__(self, out: str | os.PathLike, names: list[str], rows: list[dict] | None = None):
        files = TrainingFolder(out)
        self.csv = Path(files.curve("csv"))
        self.png = Path(files.curve("png"))
        self.names = list(names)
        self.rows: list[dict] = [dict(r) for r in rows or []]
        self._rewrite()

    @property
    def fields(self) -> list[str]:
        return ["step", "elapsed_s"] + self.names

    def _rewrite(self) -> None:
        with io.atomic_path(self.csv) as tmp, open(tmp, "w", newline="") as f:
            w = csv.DictWriter(f, fieldnames=self.fields)
            w.writeheader()
            for r in self.rows:
                w.writerow({k: r.get(k, "") for k in self.fields})

    def append(self, step: int, elapsed: float, values: dict[str, float]) -> None:
        row = {"step": step, "elapsed_s": f"{elapsed:.2f}"}
        row.update({k: f"{float(v):.6g}" for k, v in values.items()})
        self.rows.append(row)
        with open(self.csv, "a", newline="") as f:
            csv.DictWriter(f, fieldnames=self.fields).writerow({k: row.get(k, "") for k in self.fields})

    def plot(self, title: str) -> None:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        fig, ax = plt.subplots(figsize=(6, 3.5), dpi=100)
        steps = np.array([int(r["step"]) for r in self.rows])
        for name in self.names:
            vals = np.array([float(r[name]) if r.get(name) not in (None, "") else np.nan for r in self.rows])
            if not np.isfinite(vals).any():
                continue
            line = ax.plot(steps, vals, alpha=0.25, lw=0.8)[0]
            k = max(1, len(vals) // 50)
            smooth = np.convolve(np.nan_to_num(vals), np.ones(k) / k, mode="valid")
            ax.plot(steps[k - 1 :], smooth, color=line.get_color(), label=name)
        ax.set_yscale("log")
        ax.set_xlabel("step")
        ax.set_title(title)
        ax.legend(fontsize=7)
        fig.tight_layout()
        with io.atomic_path(self.png) as tmp:
            fig.savefig(tmp)
        plt.close(fig)


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


# -- the training loop ------------------------------------------------------------------------------------------

CHECKPOINT_FORMAT = 2  # checkpoints of another format (or none) are never resumed


def fingerprint_config(tcfg) -> dict:
    """A training-config dataclass as a fingerprint entry: every field but ``checkpoint_every`` (how often a run
    is saved does not change what it trains, so changing it keeps a run resumable)."""
    return {k: v for k, v in dataclasses.asdict(tcfg).items() if k != "checkpoint_every"}


def fingerprint(arch: dict, tcfg, steps: int, seed: int, **extra) -> dict:
    """What a run's checkpoint must agree on to be continued (:func:`config_digest` of it): the architecture, the
    training config (:func:`fingerprint_config`), the steps, the seed and the trainer's ``extra`` entries (its
    data's :func:`data_digest`, frozen models' hashes, ...)."""
    return {"arch": arch, "train": fingerprint_config(tcfg), "steps": steps, "seed": seed, **extra}


def config_digest(fingerprint: dict) -> str:
    """sha256 of a training fingerprint (JSON with sorted keys; tuples as lists, other values by ``str``)."""
    text = json.dumps(fingerprint, sort_keys=True, separators=(",", ":"), default=str)
    return hashlib.sha256(text.encode()).hexdigest()


def data_digest(obj) -> str:
    """sha256 of training data held in memory: tensors and arrays (dtype, shape, bytes), dataclasses, dicts (in
    their order), lists/tuples, strings and numbers, walked recursively. What the fingerprints record of the
    objects a run trains on, so that a resume never continues on other data under the same object ids."""
    h = hashlib.sha256()

    def walk(x) -> None:
        if isinstance(x, torch.Tensor):
            t = x.detach().cpu().contiguous()
            h.update(f"T{t.dtype}{tuple(t.shape)}".encode())
            h.update(t.view(torch.uint8).numpy().tobytes() if t.numel() else b"")
        elif isinstance(x, np.ndarray):
            a = np.ascontiguousarray(x)
            h.update(f"A{a.dtype}{a.shape}".encode())
            h.update(a.tobytes())
        elif dataclasses.is_dataclass(x) and not isinstance(x, type):
            h.update(f"D{type(x).__name__}".encode())
            for f in dataclasses.fields(x):
                h.update(f.name.encode())
                walk(getattr(x, f.name))
        elif isinstance(x, dict):
            h.update(f"M{len(x)}".encode())
            for k, v in x.items():
                walk(k)
                walk(v)
        elif isinstance(x, (list, tuple)):
            h.update(f"L{len(x)}".encode())
            for v in x:
                walk(v)
        else:
            h.update(f"S{type(x).__name__}:{x!r};".encode())

    walk(obj)
    return h.hexdigest()


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


def _plain(x):
    """Random states in the plain data a safe load accepts (:func:`frng.io.load_torch`): numpy arrays (numpy's
    MT19937 key) become ``{"__ndarray__": list, "dtype": str}``."""
    if isinstance(x, np.ndarray):
        return {"__ndarray__": x.tolist(), "dtype": str(x.dtype)}
    if isinstance(x, np.generic):
        return x.item()
    if isinstance(x, dict):
        return {k: _plain(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return type(x)(_plain(v) for v in x)
    return x


def _unplain(x):
    if isinstance(x, dict):
        if "__ndarray__" in x:
            return np.asarray(x["__ndarray__"], dtype=x["dtype"])
        return {k: _unplain(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return type(x)(_unplain(v) for v in x)
    return x


def rng_state(device: torch.device | str | None = None, rngs: dict | None = None) -> dict:
    """Every random state a training step may draw from: python's, numpy's and torch's global generators, the
    CUDA generator of ``device`` (when it is a GPU), and the trainer's own generators ``rngs`` (name -> a
    ``random.Random``, ``torch.Generator`` or numpy generator)."""
    state = {
        "python": random.getstate(),
        "numpy": _plain(np.random.get_state()),
        "torch": torch.get_rng_state(),
        "trainer": {k: _plain(_rng_get(r)) for k, r in (rngs or {}).items()},
    }
    if device is not None and torch.device(device).type == "cuda":
        state["cuda"] = torch.cuda.get_rng_state(torch.device(device))
    return state


def set_rng_state(state: dict, device: torch.device | str | None = None, rngs: dict | None = None) -> None:
    """Restore what :func:`rng_state` captured."""
    random.setstate(state["python"])
    np.random.set_state(_unplain(state["numpy"]))
    torch.set_rng_state(state["torch"])
    if "cuda" in state and device is not None and torch.device(device).type == "cuda":
        torch.cuda.set_rng_state(state["cuda"], torch.device(device))
    for k, r in (rngs or {}).items():
        _rng_set(r, _unplain(state["trainer"][k]))


def _identity(x):
    return x


def _as_list(x) -> list:
    return [x]


def _noop() -> None:
    return None


@dataclass
class FitHooks:
    """What a data-parallel trainer plugs into :func:`fit` (the defaults are a single process); see
    :func:`frng.distributed.fit_hooks`. ``reduce_logs``: this rank's step logs -> the logs of the whole step
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


def fit(
    step_fn: Callable[[int], dict[str, float]],
    tcfg,
    *,
    model: torch.nn.Module,
    optimizer: torch.optim.Optimizer,
    out: str | os.PathLike,
    total: int,
    fingerprint: dict,
    loss_names: list[str],
    save_model: Callable[[Path], None],
    summary: Callable[[FitRun], dict],
    title: str,
    desc: str,
    params: list[torch.nn.Parameter] | None = None,
    postfix: tuple[str, ...] = ("total",),
    rngs: dict | None = None,
    device: torch.device | str | None = None,
    stop_after: int | None = None,
    hooks: FitHooks | None = None,
) -> Path:
    """Run (or resume) a training run of ``total`` steps in ``out``; returns ``out/model.pt`` (the checkpoint's
    path when stopped by ``stop_after``).

    The trainer builds the model, optimiser and data, seeds, and hands over ``step_fn(step) -> logs``: one
    step's forward and backward passes (the gradients start at None) returning the step's scalar loss terms
    (named in ``loss_names``; ``total`` first), and its training config ``tcfg`` (any object with ``lr``,
    ``warmup``, ``grad_clip`` and ``checkpoint_every``). fit owns the rest:

    - resume: :func:`load_resumable` with the digest of ``fingerprint`` (+ world size); a resumed run restores
      the model, optimiser, every random state (:func:`rng_state`: global generators, the trainer's ``rngs``, per
      rank), the loss history and the elapsed time, so a killed and resumed run ends where an uninterrupted one
      does (bit-exact on a CPU) and its ``loss.csv`` covers every step. A checkpoint that is not resumed is
      deleted (it would describe another run);
    - the learning rate of step s: :func:`cosine_lr` (warm-up + cosine), times the group's ``lr_mult`` if any;
    - clipping the gradient norm of ``params`` (default: the model's, in its order; the order fixes the norm's
      rounding) to ``grad_clip``, and no update on a step whose norm is not finite (the step is still logged; the
      bar says so);
    - ``loss.csv`` / ``loss.png`` (:class:`LossLog`, rank 0), the progress bar (rank 0);
    - atomic checkpoints every ``checkpoint_every`` steps, at ``stop_after`` (tests of resumption), and once the
      model is saved a final one (``step == total``, the marker of a finished run);
    - at the end (rank 0): ``save_model(TrainingFolder(out).model())`` then ``train.json`` = ``summary(FitRun)``.

    ``hooks``: data parallelism (:class:`FitHooks`); the trainer's ``step_fn`` runs its DDP-wrapped module.
    """
    hooks = hooks or FitHooks()
    params = list(model.parameters()) if params is None else params
    lr, warmup, grad_clip = tcfg.lr, tcfg.warmup, tcfg.grad_clip
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    files = TrainingFolder(out)
    ckpt_path = Path(files.checkpoint())
    digest = config_digest({"fingerprint": fingerprint, "world_size": hooks.world_size})
    state, why = load_resumable(out, digest, total)
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
    log = LossLog(out, loss_names, state["history"] if state else None) if hooks.is_main else None
    timer = Timer(float(state["elapsed"]) if state else 0.0)
    run = FitRun(steps=total, start=start, wall_s=0.0)
    every = max(1, int(tcfg.checkpoint_every))

    def checkpoint(step: int) -> None:
        states = hooks.gather(rng_state(device, rngs))  # collective
        if hooks.is_main:
            save_torch(
                {
                    "format": CHECKPOINT_FORMAT,
                    "step": step,
                    "total": total,
                    "digest": digest,
                    "fingerprint": _plain(fingerprint),
                    "model": model.state_dict(),
                    "optimizer": optimizer.state_dict(),
                    "rng": states,
                    "history": _plain(log.rows),
                    "elapsed": float(timer.elapsed()),
                },
                ckpt_path,
            )  # plain data: loaded with weights_only
        hooks.barrier()

    model.train()
    bar = tqdm(
        range(start, total), initial=start, total=total, desc=desc, dynamic_ncols=True, disable=not hooks.is_main
    )
    ran = 0
    for step in bar:
        t0 = time.time()
        lr_now = cosine_lr(step, total, lr, warmup)
        for g in optimizer.param_groups:
            g["lr"] = float(lr_now * g.get("lr_mult", 1.0))  # a python float: checkpoints hold plain data
        optimizer.zero_grad(set_to_none=True)
        logs = step_fn(step)
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
        bar.set_postfix({("loss" if k == "total" else k): f"{logs[k]:.4f}" for k in postfix})
        ran += 1
        due = (step + 1) % every == 0 and step + 1 < total
        stop = stop_after is not None and ran >= stop_after and step + 1 < total
        if due or stop:
            checkpoint(step + 1)
        if due and log:
            log.plot(title)
        if stop:
            return ckpt_path
    bar.close()
    path = Path(files.model())
    if hooks.is_main:
        log.plot(title)
        save_model(path)
        run.wall_s = timer.elapsed()
        io.write_json(files.summary(), {**summary(run), "threads": torch.get_num_threads()})  # the weights depend on it
    checkpoint(total)  # after the model: a finished checkpoint is never resumed (load_resumable)
    return path


# -- the priors' trainers (:mod:`frng.priors.backbone_train`, :mod:`frng.priors.idm_train`) -----------------------


def check_training_split(objects: list, stage: str) -> None:
    """A priors trainer sees training objects only, and at least one."""
    if any(o.split != "train" for o in objects):
        raise ValueError(f"{stage} must only see training objects")
    if not objects:
        raise ValueError(f"{stage}: no training objects")
