"""Where torch runs and how: the device (:func:`resolve_device`), bf16 where the hardware has it (:func:`bf16_ok`,
:func:`autocast`), the intra-op thread count a training runs with (:func:`training_threads`), and timing on it
(:func:`synchronize`, :func:`median_time`), and deterministic kernels on a CPU (:func:`deterministic_kernels`)."""

from __future__ import annotations

import contextlib
import functools
import os
import statistics
import time
from pathlib import Path

import torch


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


def deterministic_kernels(device: torch.device | str | None = None) -> bool:
    """Switch torch to its deterministic kernels when training on a CPU; returns whether they are on.

    With two or more threads, ``index_put_(accumulate=True)`` -- the backward of every advanced-indexing read
    ``x[idx]`` -- splits its sums between threads in whatever order they run, so two runs of the same config
    differed in the 7th digit after a few steps and the default tier's backbone (1000 steps) ended with different
    weights (measured; ``tests/test_determinism.py`` reproduces it in-process). Deterministic mode sorts the indices
    first: same sums as ``index_add_``, no measurable cost at the default tier. Uninitialised memory is not filled
    (torch's deterministic-mode default), which only costs time. Left alone on a GPU: gsplat's rasterizer
    accumulates with atomics regardless, and some CUDA kernels have no deterministic version."""
    if device is not None and torch.device(device).type != "cpu":
        return torch.are_deterministic_algorithms_enabled()
    torch.use_deterministic_algorithms(True, warn_only=True)
    torch.utils.deterministic.fill_uninitialized_memory = False
    return True


def synchronize(device: torch.device) -> None:
    """Wait for ``device``'s queued work (CUDA); a no-op on a CPU. What a wall-clock timing brackets its block with."""
    if device.type == "cuda":
        torch.cuda.synchronize(device)


def median_time(fn, device: torch.device, repeats: int, warmup: bool = True):
    """(median seconds of ``fn()`` over ``repeats`` runs after one warm-up (none with ``warmup=False``: the caller
    warmed the code path up some cheaper way), synchronised on ``device``; the last run's result)."""
    out = fn() if warmup else None
    ts = []
    for _ in range(repeats):
        synchronize(device)
        t = time.perf_counter()
        out = fn()
        synchronize(device)
        ts.append(time.perf_counter() - t)
    return statistics.median(ts), out
