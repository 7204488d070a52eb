"""Digests: of a file's bytes (:func:`file_sha256`, what caches record of the models they were made with), of
training data held in memory (:func:`data_digest`) and of a training fingerprint (:func:`config_digest`).
Torch-free (:mod:`frng.io` hashes with it in curation jobs): :func:`data_digest` recognises tensors only when torch
is already imported, as it must be for one to exist."""

from __future__ import annotations

import dataclasses
import functools
import hashlib
import json
import os
import sys
import time

import numpy as np


def file_sha256(path: str | os.PathLike) -> str:
    """sha256 of a file's bytes (hex). Memoised per process on the file's identity and change times (inode, size,
    mtime, ctime): loading a training split's caches checks each against the same model file (~120 hashes of one
    file per training job); a rewritten or replaced file has another identity and is hashed again. A file changed
    in the last two seconds is always hashed (file times are coarser than a fast in-place rewrite, as git's "racy"
    entries)."""
    st = os.stat(path)
    if time.time_ns() - max(st.st_mtime_ns, st.st_ctime_ns) < 2 * 10**9:
        return _sha256_of.__wrapped__(path, st.st_ino, st.st_size, st.st_mtime_ns, st.st_ctime_ns)
    return _sha256_of(os.path.realpath(path), st.st_ino, st.st_size, st.st_mtime_ns, st.st_ctime_ns)


@functools.lru_cache(maxsize=64)
def _sha256_of(path: str, ino: int, size: int, mtime_ns: int, ctime_ns: int) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def config_digest(fingerprint: dict) -> str:
    """sha256 of a training fingerprint (JSON with sorted keys; tuples as lists, other values by ``str``)."""
    text = json.dumps(fingerprint, sort_keys=True, separators=(",", ":"), default=str)
    return hashlib.sha256(text.encode()).hexdigest()


def data_digest(obj) -> str:
    """sha256 of training data held in memory: tensors and arrays (dtype, shape, bytes), dataclasses, dicts (in
    their order), lists/tuples, strings and numbers, walked recursively. What the fingerprints record of the
    objects a run trains on, so that a resume never continues on other data under the same object ids."""
    h = hashlib.sha256()
    torch = sys.modules.get("torch")

    def walk(x) -> None:
        if torch is not None and isinstance(x, torch.Tensor):
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
