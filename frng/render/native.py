"""The project's C++ (OpenMP) CPU kernels: the tile rasterizer's (``frng/render/csrc/composite.cpp``) and the
visual hull's sweep (``csrc/hull.cpp``); build, load, wrappers.

:func:`composite_tiles` is a drop-in for :func:`frng.render.tiles.composite_tiles` on CPU: the same inputs and
outputs, the same alpha rule (constants from :mod:`frng.render.project`), forward and 3DGS-style backward fused per
tile, parallel over tiles with torch's thread count and deterministic (per-worker gradient buffers summed in a fixed
order: the same thread count gives the same bytes). float32 (AVX2 or baseline x86-64 code, chosen at load time, the
same bits either way) and float64. :func:`bin_tiles` builds the rows of :func:`frng.render.tiles.bin_pairs`'s
tile table by a counting sort (bit for bit the same rows, concatenated instead of padded). :func:`hull_occupancy`
is the backbone's multi-view cue sweep (:func:`frng.priors.multiview.rays_occupancy`), the same floats as its
PyTorch reference.

One difference from the PyTorch compositor: early termination is per pixel (a pixel stops right after the
Gaussian that takes its transmittance below ``min_transmittance``), where the PyTorch path stops a whole tile
after the depth chunk in which all its pixels fell below it. Both leave out less than ``min_transmittance`` of
each pixel's weight, so they differ by less than ``min_transmittance * max|feature|``; with
``min_transmittance=0`` both composite every Gaussian.

Build: ``torch.utils.cpp_extension.load`` (ninja, the C++ compiler torch was built with) with portable ``-O3``
(no ``-march=native``: the file may run on other CPUs) into ``build/native/<torch>-<python>-<hash of source and
flags>/`` of the repository (in a non-editable install: next to the source), never ~/.cache. Each build goes
to a private temporary folder and the library is moved into place, so concurrent or interrupted builds leave no
stale lock. ``python -m frng.render.native --build`` (``make setup``) builds it once; :func:`available` otherwise
builds it on first use, and with a one-line warning naming the reason returns False when that fails (callers
then use the PyTorch kernels).
"""

from __future__ import annotations

import contextlib
import hashlib
import importlib.machinery
import importlib.util
import math
import os
import shutil
import sys
import tempfile
import warnings
from pathlib import Path

import torch

from frng.render.project import ALPHA_MAX, ALPHA_MIN, SIGMA_CUTOFF

NAME = "frng_composite"
SOURCE = Path(__file__).parent / "csrc" / "composite.cpp"  # the rasterizer's kernels and the module's bindings
SOURCES = (SOURCE, SOURCE.parent / "hull.cpp")  # + the visual hull's occupancy (frng.priors.multiview.occupancy)
# -ffp-contract=off: forward and backward must recompute bit-identical alphas (the backward re-takes the cut-off
# decisions); -fno-trapping-math lets the alpha loop vectorise (no FP exception is observed; values unchanged);
# -fopenmp for ATen's at::parallel_for (the library then shares torch's libgomp)
CFLAGS = ("-O3", "-ffp-contract=off", "-fno-trapping-math", "-fopenmp")
LDFLAGS = ("-fopenmp",)

_state: dict = {}  # "module" once loaded, "error" once a load failed (tried once per process)


def build_dir() -> Path:
    """Folder of the built library: ``<repo>/build/native/<torch>-<python>-<hash>`` in a checkout (the repository's
    .gitignore covers /build/), ``frng/render/csrc/build/...`` in an installed package."""
    digest = hashlib.sha256(
        b"".join(p.read_bytes() for p in SOURCES) + " ".join(CFLAGS + LDFLAGS).encode()
    ).hexdigest()[:12]
    tag = f"torch{torch.__version__}-py{sys.version_info[0]}{sys.version_info[1]}-{digest}"
    repo = Path(__file__).resolve().parents[2]
    root = repo / "build" if (repo / "pyproject.toml").exists() else SOURCE.parent / "build"
    return root / "native" / tag


def _library() -> Path:
    return build_dir() / f"{NAME}.so"


def _import(path: Path):
    loader = importlib.machinery.ExtensionFileLoader(NAME, str(path))
    spec = importlib.util.spec_from_file_location(NAME, str(path), loader=loader)
    module = importlib.util.module_from_spec(spec)
    loader.exec_module(module)
    return module


def _compile():
    """Compile into a private temporary folder next to the final one, move the library into place and return the
    module (as ``cpp_extension.load`` imported it)."""
    from torch.utils import cpp_extension

    final = _library()
    final.parent.mkdir(parents=True, exist_ok=True)
    old_path = os.environ.get("PATH", "")
    if shutil.which("ninja") is None:  # the pip package's binary, when the venv's bin/ is not on PATH
        try:
            import ninja

            os.environ["PATH"] = ninja.BIN_DIR + os.pathsep + old_path
        except ImportError:
            pass
    tmp = Path(tempfile.mkdtemp(prefix=".build-", dir=final.parent))
    try:
        module = cpp_extension.load(
            name=NAME,
            sources=[str(p) for p in SOURCES],
            extra_cflags=list(CFLAGS),  # copies: load() appends to the lists it is given
            extra_ldflags=list(LDFLAGS),
            build_directory=str(tmp),
            verbose=False,
        )
        built = next(tmp.glob(f"{NAME}*.so"))  # load() names it NAME_v1, ... on a second build in one process
        os.replace(built, final)  # atomic: a concurrent build writes the same file
    finally:
        os.environ["PATH"] = old_path
        shutil.rmtree(tmp, ignore_errors=True)
        if not final.exists():  # failed: leave no empty folder behind
            with contextlib.suppress(OSError):
                final.parent.rmdir()
    return module


def _reason(err: BaseException) -> str:
    """One line naming why the build or load failed (the compiler's first error line when there is one)."""
    lines = [line.strip() for line in str(err).splitlines() if line.strip()]
    errors = [line for line in lines[1:] if "error" in line.lower()]
    first = lines[0].split(": [", 1)[0][:200] if lines else ""  # not ninja's compiler command line
    return f"{type(err).__name__}: {first}" + (f" ({errors[0][:300]})" if errors else "")


def load():
    """The extension module (built on first use); raises when it cannot be built or loaded."""
    if "module" not in _state:
        if "error" in _state:
            raise RuntimeError(_state["error"])
        try:
            lib = _library()
            _state["module"] = _import(lib) if lib.exists() else _compile()
        except Exception as err:  # compiler missing or failing, ninja missing, ABI mismatch, ...
            _state["error"] = _reason(err)
            raise
    return _state["module"]


def reason() -> str | None:
    """Why the extension is unavailable (None when it loaded or was not tried yet)."""
    return _state.get("error")


def available() -> bool:
    """True when the extension builds and loads (tried once per process; on failure one warning with the reason)."""
    if "module" in _state:
        return True
    if "error" in _state:
        return False
    try:
        load()
    except Exception:
        warnings.warn(
            f"frng.render.native: C++ kernels unavailable, using the PyTorch ones ({_state['error']})",
            stacklevel=2,
        )
        return False
    return True


def _cuts() -> tuple[float, float, float]:
    return ALPHA_MIN, ALPHA_MAX, math.exp(-0.5 * SIGMA_CUTOFF**2)


class _NativeComposite(torch.autograd.Function):
    """Forward and backward of every tile's compositing in the C++ kernel (once differentiable)."""

    @staticmethod
    def forward(ctx, params, f_inst, ids, starts, counts, pix, origin, min_transmittance):
        args = (params, f_inst, ids, starts, counts, pix, origin)
        out, T, last = load().forward(*args, float(min_transmittance), *_cuts())
        ctx.save_for_backward(*args, T, last)
        return out, T

    @staticmethod
    @torch.autograd.function.once_differentiable
    def backward(ctx, g_out, g_T):
        *args, T, last = ctx.saved_tensors
        d_params, d_f = load().backward(*args, T, last, g_out.contiguous(), g_T.contiguous(), *_cuts())
        return d_params, d_f, None, None, None, None, None, None


def composite_tiles(params, f_inst, table, counts, pix, origin, min_transmittance=1e-4):
    """Differentiable front-to-back compositing of every tile in the C++ kernel; inputs and outputs as
    :func:`frng.render.tiles.composite_tiles` (which see), except that early termination is per pixel and that
    ``table`` may also come concatenated.

    params: (M + 1, 6); f_inst: (M + 1, D); table: (T, K_max) int64 padded rows, or (L,) int64 the rows
    concatenated (``bin_pairs(..., kernel="native")``; tile t's are the counts[t] after sum(counts[:t])), entries
    in [0, M]; counts: (T,) int64; pix: (P, 2); origin: (T, 6). Returns features (T, P, D) and final transmittance
    (T, P).
    """
    n_tiles = counts.shape[0]
    assert params.dim() == 2 and params.shape[1] == 6, params.shape
    assert f_inst.dim() == 2 and f_inst.shape[0] == params.shape[0], (f_inst.shape, params.shape)
    assert counts.shape == (n_tiles,) and origin.shape[0] == n_tiles, (counts.shape, origin.shape)
    assert table.dim() == 1 or table.shape[0] == n_tiles, (table.shape, counts.shape)
    assert pix.dim() == 2 and pix.shape[1] == 2, pix.shape
    assert params.device.type == "cpu", "the native compositor runs on CPU"
    counts = counts.long().contiguous()
    if table.dim() == 2:  # padded: row t starts at t * K_max
        starts = torch.arange(n_tiles, dtype=torch.long) * table.shape[1]
    else:  # concatenated
        starts = torch.cumsum(counts, 0) - counts
    dtype = f_inst.dtype
    return _NativeComposite.apply(
        params.to(dtype).contiguous(),
        f_inst.contiguous(),
        table.long().reshape(-1).contiguous(),
        starts,
        counts,
        pix.to(dtype).contiguous(),
        origin.to(dtype).contiguous(),
        min_transmittance,
    )


def bin_tiles(mean2d, extent, inst, TY, TX, tile):
    """The rows of :func:`frng.render.tiles.bin_pairs`'s tile table by a counting sort in C++ (bit for bit the same
    rows), concatenated instead of padded.

    mean2d, extent: (V, N, 2) centres and 3-sigma half-widths (:class:`frng.render.project.Projected`); inst: (M,)
    int64 flat (view * N + n) indices of the valid instances in depth order. Returns ids (L,) int64 (tile after tile,
    each tile's instance positions into ``inst`` in depth order) and counts (V * TY * TX,) int64.
    """
    V, N = mean2d.shape[:2]
    assert mean2d.shape == (V, N, 2) and extent.shape == (V, N, 2) and inst.dim() == 1, (mean2d.shape, extent.shape)
    m = mean2d.detach().reshape(V * N, 2).contiguous()
    return load().bin_tiles(m, extent.to(m.dtype).reshape(V * N, 2).contiguous(), inst.long(), V, N, TY, TX, tile)


def hull_occupancy(
    alpha: torch.Tensor, A: torch.Tensor, B: torch.Tensor, t: torch.Tensor, stop: float | None = None
) -> torch.Tensor:
    """The visual hull's occupancy along rays in C++ (``csrc/hull.cpp``; the reference is
    :func:`frng.priors.multiview.occupancy_reference`): per sample the minimum over views of the mask read
    bilinearly where it projects, 0 behind a camera.

    alpha (V, H, W) masks; A, B (V, R, 3) the rays' homogeneous image coordinates h = A + t B
    (:func:`frng.priors.multiview.ray_homogeneous`); t (R, K) sample distances. Returns (R, K) float32.
    ``stop``: a ray's samples after its first with occupancy >= ``stop`` are 0 (not computed; None: all are)."""
    V, R = A.shape[:2]
    assert alpha.dim() == 3 and alpha.shape[0] == V, (alpha.shape, A.shape)
    assert A.shape == (V, R, 3) and B.shape == A.shape and t.dim() == 2 and t.shape[0] == R, (A.shape, B.shape, t.shape)
    f = [x.detach().float().contiguous() for x in (alpha, A, B, t)]
    return load().hull_occupancy(*f, math.nan if stop is None else float(stop))


def main(argv: list[str] | None = None) -> int:
    """``python -m frng.render.native --build``: build the extension now (``make setup``); exit 1 on failure."""
    import argparse

    parser = argparse.ArgumentParser(prog="python -m frng.render.native", description=main.__doc__)
    parser.add_argument("--build", action="store_true", help="build (if needed) and load the extension")
    args = parser.parse_args(argv)
    if not args.build:
        parser.print_help()
        return 0
    try:
        load()
    except Exception:
        print(f"frng.render.native: build failed ({_state['error']}); the PyTorch kernels will be used")
        return 1
    print(f"frng.render.native: {_library()}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
