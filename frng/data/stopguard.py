"""Ending a Blender job on SIGINT / SIGTERM without leaving partial output: :class:`StopGuard` (installed by the
``curate`` and ``envmaps`` stages) and :class:`NoGuard` (its interface without signal handling, for library use)."""

from __future__ import annotations

import contextlib
import os
import shutil
import signal
import sys
import threading
from pathlib import Path

STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM)


class StopGuard:
    """SIGINT (Ctrl-C) and SIGTERM (scancel, a job killed by its scheduler) end the process at once -- also in the
    middle of a Cycles render -- after removing the paths registered in :attr:`paths`; exit status 128 + signal.

    Why not Python's ordinary handlers: ``import bpy`` installs Blender's own SIGINT handler (in background mode it
    only cancels the image being rendered, so a curation ran on and exited 0), and re-installing Python's does not
    help either: Cycles renders through Python (``cycles.engine.render``), so the KeyboardInterrupt is raised
    inside Blender's callback, which prints it and carries on. Here the C-level handler only writes the signal
    number to a pipe (``signal.set_wakeup_fd``); a thread waiting on it (Blender releases the GIL while it renders)
    takes :attr:`lock`, removes the paths and calls ``os._exit``. The main thread holds :attr:`lock` while it
    writes into a registered path, so the removal never races a write.

    ``os._exit`` skips Blender's own exit, which removes its per-process temporary folder (``bpy.app.tempdir``,
    ``$TMPDIR/blender_*``): the guard removes that folder too when bpy is loaded, so a stopped job leaves nothing in
    the temporary directory either.

    Installed by the stages only (``frng curate``, ``frng envmaps``): a library caller keeps its own handlers.
    """

    def __init__(self, name: str):
        self.name = name
        self.lock = threading.RLock()
        self.paths: list[Path] = []

    def install(self) -> StopGuard:
        r, w = os.pipe()
        os.set_blocking(w, False)
        for sig in STOP_SIGNALS:
            signal.signal(sig, lambda signum, frame: None)  # Python's C handler (replacing Blender's) + wakeup fd
        signal.set_wakeup_fd(w, warn_on_full_buffer=False)
        threading.Thread(target=self._watch, args=(r,), name="frng-stop-guard", daemon=True).start()
        return self

    def _watch(self, fd: int) -> None:
        while True:
            stops = [b for b in os.read(fd, 64) if b in STOP_SIGNALS]
            if stops:
                break
        signum = stops[0]
        self.lock.acquire()  # never released: nothing is written after this
        bpy = sys.modules.get("bpy")
        for path in [*self.paths, *([Path(bpy.app.tempdir)] if bpy is not None and bpy.app.tempdir else [])]:
            shutil.rmtree(path, ignore_errors=True)
        os.write(2, f"{self.name}: stopped by {signal.Signals(signum).name}; removed the partial output\n".encode())
        os._exit(128 + signum)


class NoGuard:
    """:class:`StopGuard`'s interface without signal handling (library use of :func:`frng.data.curate.curate`, :func:`frng.data.envmaps.prepare`)."""

    def __init__(self):
        self.lock = contextlib.nullcontext()
        self.paths: list[Path] = []
