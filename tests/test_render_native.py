"""The fused C++ CPU kernels (``backend="native"``, frng/render/native.py) against the brute-force reference and
the PyTorch tile backend: values, gradients, the binning table, gradcheck, determinism, the ``auto`` choice and the
fallback.

Tolerances: with early termination off (min_transmittance=0) the native kernel computes the reference's sums in
another order, so float64 values and gradients agree to 1e-9. With it on, each pixel stops once its transmittance
is below min_transmittance (the PyTorch backend stops whole tiles per depth chunk), so outputs differ by less than
min_transmittance x max|feature|.
"""

import warnings

import pytest
import torch
from test_render_raster import DT, _cams, _grads, _scene

from frng.render import native, rasterize
from frng.render.project import project_gaussians
from frng.render.raster import resolve_backend
from frng.render.scenes import pixel_aligned_scene
from frng.render.tiles import bin_pairs

NAMES = ["means", "quats", "scales", "opacities", "features"]


@pytest.fixture(autouse=True, scope="module")
def _needs_native():
    if not native.available():
        pytest.skip(f"the C++ compositor does not build here: {native.reason()}")


def _hard_scene(V=3, C=4, per_view=False, seed=0):
    """_scene plus a pile of 40 overlapping Gaussians, one behind the first camera, one just past its near plane
    and one at its centre; per-view features (V, N, C) when ``per_view``."""
    c2w, _ = _cams([0, 75, 200][:V], 22, 26)
    params = _scene(N=80, C=C, seed=seed)
    g = torch.Generator().manual_seed(seed + 100)
    eye, fwd = c2w[0, :3, 3], c2w[0, :3, 2]
    pile = torch.randn(40, 3, generator=g, dtype=DT) * 0.03 + torch.tensor([0.1, 0.0, 0.1], dtype=DT)
    odd = torch.stack([eye - 0.5 * fwd, eye + 0.02 * fwd, eye])
    extra = [
        torch.cat([pile, odd]),
        torch.randn(43, 4, generator=g, dtype=DT),
        torch.rand(43, 3, generator=g, dtype=DT) * 0.05 + 0.02,
        torch.rand(43, generator=g, dtype=DT) * 0.9 + 0.05,
        torch.randn(43, C, generator=g, dtype=DT),
    ]
    params = [torch.cat([a, b]) for a, b in zip(params, extra)]
    if per_view:
        params[4] = torch.randn(V, params[0].shape[0], C, generator=g, dtype=DT)
    return params


@pytest.mark.parametrize("tile,per_view", [(4, False), (8, True), (5, False)])
def test_native_matches_reference_values_and_gradients(tile, per_view):
    H, W = 22, 26  # not a multiple of the tile size: cropped border tiles
    c2w, K = _cams([0, 75, 200], H, W)
    params = [p.clone().requires_grad_() for p in _hard_scene(per_view=per_view)]
    nat = rasterize(*params, c2w, K, H, W, backend="native", tile_size=tile, min_transmittance=0.0)
    ref = rasterize(*params, c2w, K, H, W, backend="reference")
    for a, b, name in zip(nat, ref, ["features", "alpha", "depth"]):
        assert a.shape == b.shape
        assert torch.allclose(a, b, atol=1e-9, rtol=0), name
    assert ref[1].max() > 0.9 and (ref[1] == 0).any()  # opaque pixels and empty tiles
    for ga, gb, name in zip(_grads(nat, params), _grads(ref, params), NAMES):
        assert torch.isfinite(ga).all()
        assert gb.abs().max() > 0, name
        assert torch.allclose(ga, gb, atol=1e-9 * max(1.0, gb.abs().max().item()), rtol=1e-7), name


def test_native_float32_matches_torch_backend():
    """float32, with and without early termination: the native and PyTorch tile backends agree (values within
    min_transmittance x max|feature|, gradients to float32 precision)."""
    H, W = 24, 24
    c2w, K = _cams([10, 130], H, W)
    params = _scene(N=300, C=3, seed=3)
    params[3] = torch.full_like(params[3], 0.9)  # opaque: early termination kicks in
    params = [p.float().requires_grad_() for p in params]
    c2w, K = c2w.float(), K.float()
    zmax = torch.linalg.inv(c2w)[:, 2, :3].matmul(params[0].detach().T).add(torch.linalg.inv(c2w)[:, 2, 3:]).max()
    scale = [params[4].abs().max().item(), 1.0, zmax.item()]  # max |feature| of each output: features, alpha, z
    for min_t in [0.0, 1e-4]:
        nat = rasterize(*params, c2w, K, H, W, backend="native", min_transmittance=min_t)
        tor = rasterize(*params, c2w, K, H, W, backend="torch", min_transmittance=min_t)
        for a, b, m, name in zip(nat, tor, scale, ["features", "alpha", "depth"]):
            assert (a - b).abs().max() < max(min_t, 1e-6) * m + 1e-5, (name, min_t)
        for ga, gb, name in zip(_grads(nat, params), _grads(tor, params), NAMES):
            err = ((ga - gb).norm() / gb.norm()).item()
            assert err < (1e-5 if min_t == 0 else 2e-3), (name, min_t, err)


@pytest.mark.parametrize("size,tile", [(32, 4), (37, 5)])
def test_native_binning_equals_torch_binning(size, tile):
    """The C++ counting sort builds the rows of the PyTorch binning's table bit for bit (pixel-aligned scene: big
    overlaps), concatenated."""
    s = pixel_aligned_scene(size, 6, 3)
    proj = project_gaussians(
        s["means"], s["quats"], s["scales"], s["c2w"], s["intrinsics"], size, size, opacities=s["opacities"]
    )
    inst, table, counts, grid = bin_pairs(proj, size, size, tile)
    inst_n, ids, counts_n, grid_n = bin_pairs(proj, size, size, tile, kernel="native")
    assert grid == grid_n and table.shape[1] > 100
    assert torch.equal(inst, inst_n) and torch.equal(counts, counts_n)
    rows = table[torch.arange(table.shape[1]) < counts[:, None]]  # row-major: tile after tile
    assert ids.dtype == table.dtype and torch.equal(ids, rows)


def test_native_composite_takes_padded_or_concatenated_rows():
    """The drop-in signature (a padded (T, K_max) table) and the concatenated rows give the same bytes."""
    size = 24
    s = pixel_aligned_scene(size, 2, 5)
    proj = project_gaussians(
        s["means"], s["quats"], s["scales"], s["c2w"], s["intrinsics"], size, size, opacities=s["opacities"]
    )
    inst, table, counts, (TY, TX) = bin_pairs(proj, size, size, 4)
    ids = bin_pairs(proj, size, size, 4, kernel="native")[1]
    M, N = inst.numel(), s["means"].shape[0]
    g = torch.Generator().manual_seed(0)
    params = torch.cat(
        [proj.mean2d.reshape(-1, 2)[inst], proj.conic.reshape(-1, 3)[inst], s["opacities"][inst % N, None]], 1
    )
    params = torch.cat([params, params.new_zeros(1, 6)]).detach()
    f_inst = torch.randn(M + 1, 6, generator=g)
    pix = torch.stack(torch.meshgrid(torch.arange(4.0), torch.arange(4.0), indexing="xy"), -1).reshape(-1, 2) + 0.5
    t = torch.arange(counts.numel())
    origin = torch.zeros(counts.numel(), 6)
    origin[:, 0], origin[:, 1] = (t % TX) * 4.0, (t // TX % TY) * 4.0
    a = native.composite_tiles(params, f_inst, table, counts, pix, origin)
    b = native.composite_tiles(params, f_inst, ids, counts, pix, origin)
    assert a[1].min() < 0.5  # something was composited
    for x, y in zip(a, b):
        assert torch.equal(x, y)


def test_native_is_deterministic_at_two_threads():
    H, W = 32, 32
    c2w, K = _cams([0, 90, 180], H, W)
    params = [p.float().requires_grad_() for p in _scene(N=400, C=8, seed=2)]
    c2w, K = c2w.float(), K.float()
    threads = torch.get_num_threads()
    torch.set_num_threads(2)
    try:
        runs = []
        for _ in range(2):
            outs = rasterize(*params, c2w, K, H, W, backend="native")
            runs.append([o.detach() for o in outs] + list(_grads(outs, params)))
    finally:
        torch.set_num_threads(threads)
    for a, b in zip(*runs):
        assert a.numpy().tobytes() == b.numpy().tobytes()


def test_auto_picks_native_on_cpu():
    assert resolve_backend("auto", torch.device("cpu")) == "native"
    assert resolve_backend("native", torch.device("cpu")) == "native"


def test_failed_build_falls_back_to_torch(monkeypatch):
    """A failing build: one warning naming the compiler's error, ``auto`` -> ``torch``, ``native`` -> an error."""

    def broken():
        raise RuntimeError("Error building extension 'frng_composite'\ncomposite.cpp:1:1: error: boom")

    monkeypatch.setattr(native, "_state", {})
    monkeypatch.setattr(native, "_library", lambda: native.SOURCE.parent / "missing" / "none.so")
    monkeypatch.setattr(native, "_compile", broken)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        assert resolve_backend("auto", torch.device("cpu")) == "torch"
        assert resolve_backend("auto", torch.device("cpu")) == "torch"  # tried once: no second warning
    assert len(caught) == 1 and "boom" in str(caught[0].message), [str(w.message) for w in caught]
    with pytest.raises(RuntimeError, match="native"):
        resolve_backend("native", torch.device("cpu"))
