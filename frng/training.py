"""Training plumbing shared by the training stages (``frng backbone-train``, ``frng idm-train``, ``frng train``).

- :func:`resolve_device` -- ``auto`` = CUDA when present, else CPU.
- :func:`autocast` -- bf16 autocast context (CPU AMX or CUDA) or a no-op.
- :func:`train_seed` -- the learned models' seed (``train_seed``, else ``seed``);
- :func:`seed_everything` -- python / numpy / torch seeds from it.
- :class:`Checkpointer` -- atomic ``{out}/checkpoint.pt`` (model, optimiser, step, RNG states, loss history) every
  ``every`` steps; a rerun of the same command resumes from it (the interrupted run loses at most ``every`` steps).
- :class:`LossLog` -- ``{out}/loss.csv`` (one row per step: step, elapsed_s, then named loss terms) and
  ``{out}/loss.png`` (curves, log-scale y, a moving average on top of the raw values).

A finished run writes the final model file (``model.pt``) with :func:`save_model`: ``{"kind", "config",
"state_dict", "steps", "sha256"...}``; the hash is computed over the file's bytes by :func:`file_sha256` and is
what caches record to detect a stale cache.
"""

from __future__ import annotations

import contextlib
import csv
import functools
import hashlib
import os
import random
import time
from pathlib import Path

import numpy as np
import torch

from frng import io


def resolve_device(name: str = "auto") -> torch.device:
    """``auto`` -> ``cuda`` when available, else ``cpu``; ``cuda`` without a GPU is an error."""
    if name == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    if name == "cuda" and not torch.cuda.is_available():
        raise RuntimeError("config device is 'cuda' but no CUDA device is available")
    return torch.device(name)


@functools.lru_cache(maxsize=None)
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


def train_seed(config: dict) -> int:
    """The learned models' seed: ``train_seed``, or the data's ``seed`` when it is null/absent."""
    s = config.get("train_seed")
    return int(config["seed"] if s is None else s)


def seed_everything(seed: int) -> None:
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
    """``torch.save`` through a temporary file renamed into place (a killed job leaves no partial file)."""
    with io.atomic_path(path) as tmp:
        torch.save(obj, tmp)


class Checkpointer:
    """Periodic resumable checkpoints in ``out/checkpoint.pt``."""

    def __init__(self, out: str | os.PathLike, every: int):
        self.path = Path(out) / "checkpoint.pt"
        self.every = max(1, int(every))

    def load(self, model: torch.nn.Module, optimizer: torch.optim.Optimizer, fingerprint: dict) -> dict | None:
        """Restore model/optimiser/RNG from the last checkpoint; returns its dict (with ``step``) or None.

        ``fingerprint`` (architecture + training config) must match the stored one: resuming a run whose
        config changed would silently mix two trainings, so that is an error telling the user to delete it.
        """
        if not self.path.exists():
            return None
        state = torch.load(self.path, map_location="cpu", weights_only=False)
        if state.get("fingerprint") != fingerprint:
            raise RuntimeError(
                f"{self.path}: checkpoint was written with a different config; delete it to start over"
            )
        model.load_state_dict(state["model"])
        optimizer.load_state_dict(state["optimizer"])
        torch.set_rng_state(state["torch_rng"])
        np.random.set_state(state["numpy_rng"])
        random.setstate(state["python_rng"])
        return state

    def save(self, step: int, model, optimizer, fingerprint: dict, extra: dict | None = None) -> None:
        state = {
            "step": step,
            "model": model.state_dict(),
            "optimizer": optimizer.state_dict(),
            "torch_rng": torch.get_rng_state(),
            "numpy_rng": np.random.get_state(),
            "python_rng": random.getstate(),
            "fingerprint": fingerprint,
        }
        state.update(extra or {})
        save_torch(state, self.path)

    def due(self, step: int, total: int) -> bool:
        return step % self.every == 0 or step == total


class LossLog:
    """Append-only loss CSV (header written once) and a PNG plot of all terms."""

    def __init__(self, out: str | os.PathLike, names: list[str]):
        self.csv = Path(out) / "loss.csv"
        self.png = Path(out) / "loss.png"
        self.names = list(names)
        self.rows: list[dict] = []
        if self.csv.exists():
            with open(self.csv) as f:
                self.rows = [dict(r) for r in csv.DictReader(f)]

    def truncate(self, step: int) -> None:
        """Drop rows after ``step`` (a resumed run recomputes them) and rewrite the CSV."""
        self.rows = [r for r in self.rows if int(r["step"]) <= step]
        self._rewrite()

    def _rewrite(self) -> None:
        self.csv.parent.mkdir(parents=True, exist_ok=True)
        with open(self.csv, "w", newline="") as f:
            w = csv.DictWriter(f, fieldnames=["step", "elapsed_s"] + self.names)
            w.writeheader()
            for r in self.rows:
                w.writerow({k: r.get(k, "") for k in ["step", "elapsed_s"] + self.names})

    def append(self, step: int, elapsed: float, values: dict[str, float]) -> None:
        row = {"step": step, "elapsed_s": f"{elapsed:.2f}"}
        row.update({k: f"{float(v):.6g}" for k, v in values.items()})
        new_file = not self.csv.exists()
        self.rows.append(row)
        with open(self.csv, "a", newline="") as f:
            w = csv.DictWriter(f, fieldnames=["step", "elapsed_s"] + self.names)
            if new_file:
                w.writeheader()
            w.writerow({k: row.get(k, "") for k in ["step", "elapsed_s"] + self.names})

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
