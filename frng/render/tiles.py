"""Pure-PyTorch tile-binned Gaussian rasterizer (the CPU backend of :func:`frng.render.rasterize`).

Algorithm (vectorised over (tile, Gaussian) pairs; no Python loop over tiles or Gaussians):

1. EWA-project every (view, Gaussian) instance (:mod:`frng.render.project`); keep the valid ones and sort them
   once by depth.
2. Enumerate the tiles covered by each instance's 3-sigma box (``repeat_interleave``, exact, memory linear in the
   number of pairs), stable-sort the pairs by tile id: within a tile, pairs stay in depth order. Build a padded
   (tiles, K_max) table of instance ids (a sentinel instance with zero opacity pads it).
3. Composite front to back in depth chunks of ``chunk`` Gaussians for all active tiles at once: alpha from the
   conic, transmittance by an exclusive cumulative sum of ``log(1 - alpha)``, per-tile ``bmm`` of weights with
   features. After each chunk, tiles whose pixels all have transmittance below ``min_transmittance`` (early
   termination) or that ran out of Gaussians leave the active set.

Everything index-related runs under ``no_grad``; autograd differentiates the gathers and the compositing.
The result does not depend on the tile size: a Gaussian contributes only inside its 3-sigma ellipse (which is
inside its box) and only where alpha >= 1/255.
"""

from __future__ import annotations

import math

import torch

from frng.render.project import ALPHA_MAX, ALPHA_MIN, SIGMA_CUTOFF, Projected

_compiled: dict = {}
# the raster backends this module composites: the PyTorch kernels and the C++ ones (frng.render.native)
TILE_KERNELS = ("torch", "native")


def _monomials(pix: torch.Tensor) -> torch.Tensor:
    """(P, 2) tile-local pixel centres -> (P, 6) monomials 1, x, y, x^2, xy, y^2."""
    x, y = pix[:, 0], pix[:, 1]
    return torch.stack([torch.ones_like(x), x, y, x * x, x * y, y * y], dim=1)


def composite_forward(pix, g, f_ext, T_in):
    """Composite one depth chunk of Gaussians over a batch of tiles (forward of the differentiable core).

    pix: (P, 2) tile-local pixel centres; g: (B, K, 6) per-Gaussian (mx, my, conic a, b, c, opacity), means
    tile-local, in depth order; f_ext: (B, K, D) features (depth appended as the last channel); T_in: (B, P)
    transmittance before the chunk.

    The exponent -sigma + log(opacity) is a quadratic polynomial in the pixel coordinates, so the whole
    (B, P, K) log-alpha field is one batched GEMM of the (P, 6) pixel monomials with (B, 6, K) per-Gaussian
    coefficients (tile-local coordinates keep the expansion well conditioned). The 3-sigma cut and the 1/255
    cut become one per-Gaussian threshold on alpha: alpha >= max(1/255, opacity * exp(-4.5)).

    Returns out (B, P, D) = sum_k w_k f_ext_k, T_out (B, P), and the tensors the backward needs: alpha
    (B, P, K) (after cut-offs and clamp) and T_rel (B, P, K) = prod_{j<k} (1 - alpha_j).
    """
    mx, my, a, b, c, op = g.unbind(-1)
    ha, hc = 0.5 * a, 0.5 * c
    coef = torch.stack(
        [
            torch.log(op.clamp(min=1e-30)) - (ha * mx * mx + b * mx * my + hc * my * my),
            a * mx + b * my,
            b * mx + c * my,
            -ha,
            -b,
            -hc,
        ],
        dim=1,
    )  # (B, 6, K): log alpha = monomials @ coef
    alpha = torch.exp(torch.matmul(_monomials(pix), coef))
    thr = torch.clamp(op * math.exp(-0.5 * SIGMA_CUTOFF**2), min=ALPHA_MIN)
    alpha = torch.where(alpha >= thr[:, None, :], alpha, 0.0).clamp_(max=ALPHA_MAX)
    one = 1.0 - alpha
    T_incl = torch.cumprod(one, dim=-1)
    T_rel = T_incl / one
    out = torch.bmm(alpha * T_rel, f_ext) * T_in[..., None]
    T_out = T_in * T_incl[..., -1]
    return out, T_out, alpha, T_rel


def composite_backward(pix, g, f_ext, T_in, T_out, alpha, T_rel, g_out, g_T):
    """Hand-written backward of :func:`composite_forward` (3DGS's back-to-front formulas, vectorised):

    dL/dalpha_k = T_in (g_k T_k - sum_{j>k} g_j w_j / (1 - alpha_k)) - g_T T_out / (1 - alpha_k), with g_k =
    dL/dw_k; then sigma -> conic and mean through pixel-moment sums (one GEMM). Returns gradients for g
    (B, K, 6), f_ext (B, K, D), T_in (B, P).
    """
    one = 1.0 - alpha
    w_rel = alpha * T_rel
    gw = torch.bmm(g_out, f_ext.transpose(1, 2))  # dL/dw (per T_in) (B, P, K)
    gww = gw * w_rel
    d_T_in = gww.sum(-1) + g_T * T_rel[..., -1] * one[..., -1]
    tail = torch.cumsum(gww.flip(-1), -1).flip(-1) - gww  # sum_{j>k} g_j w_j
    # x = dL/dalpha * (1 - alpha) = T_in (g_k T_k (1 - alpha_k) - tail) - g_T T_out
    x = gw * T_rel * one
    x -= tail
    x *= T_in[..., None]
    x -= (g_T * T_out)[..., None]
    # dL/d(log alpha) = dL/dalpha * alpha (zero where cut; zero where clamped at ALPHA_MAX)
    x *= alpha / one
    d_log_alpha = torch.where(alpha < ALPHA_MAX, x, 0.0)
    mom = torch.matmul(_monomials(pix).t(), d_log_alpha)  # (B, 6, K) pixel sums of dlog(alpha) * monomial
    s0, sx, sy, sxx, sxy, syy = mom.unbind(1)
    mx, my, a, b, c, op = g.unbind(-1)
    # log alpha = log op - sigma; sigma = a dx^2 / 2 + b dx dy + c dy^2 / 2, dx = x - mx
    s_dx = sx - mx * s0
    s_dy = sy - my * s0
    s_dxx = sxx - 2 * mx * sx + mx * mx * s0
    s_dxy = sxy - mx * sy - my * sx + mx * my * s0
    s_dyy = syy - 2 * my * sy + my * my * s0
    d_op = torch.where(op > 0, s0 / op.clamp(min=1e-30), 0.0)
    d_g = torch.stack([a * s_dx + b * s_dy, b * s_dx + c * s_dy, -0.5 * s_dxx, -s_dxy, -0.5 * s_dyy, d_op], dim=-1)
    d_f = torch.bmm(w_rel.transpose(1, 2), g_out * T_in[..., None])
    return d_g, d_f, d_T_in


def _fns(compile_: bool):
    if not compile_:
        return composite_forward, composite_backward
    if "f" not in _compiled:
        _compiled["f"] = torch.compile(composite_forward, dynamic=True)
        _compiled["b"] = torch.compile(composite_backward, dynamic=True)
    return _compiled["f"], _compiled["b"]


def _gather(params, f_inst, origin, ids, active):
    """Per-chunk parameters (B, K, 6) (means made tile-local) and features (B, K, D) of table rows ``ids``."""
    B, K = ids.shape
    flat = ids.reshape(-1)
    g = params.index_select(0, flat).view(B, K, -1) - origin.index_select(0, active)[:, None, :]
    return g, f_inst.index_select(0, flat).view(B, K, -1)


class _CompositeTiles(torch.autograd.Function):
    """All depth chunks of all tiles in one autograd node: the forward loops over chunks with early
    termination and keeps each chunk's (alpha, T_rel); the backward walks the chunks in reverse, carrying
    dL/dT from chunk to chunk, and scatters the parameter gradients once per chunk into preallocated buffers
    (per-chunk autograd gathers would zero-fill a full-size gradient every chunk)."""

    @staticmethod
    def forward(ctx, params, f_inst, table, counts, pix, origin, chunk, min_transmittance, compile_):
        fwd, _ = _fns(compile_)
        n_tiles, P = origin.shape[0], pix.shape[0]
        D = f_inst.shape[1]
        out_t = f_inst.new_zeros(n_tiles, P, D)
        T_t = f_inst.new_ones(n_tiles, P)
        active = (counts > 0).nonzero().squeeze(1)
        T = f_inst.new_ones(active.numel(), P)
        saved = []
        kmax = table.shape[1]
        j = 0
        while active.numel() and j < kmax:
            ids = table.index_select(0, active)[:, j : j + chunk]  # (B, K) rows of params, depth order
            g, f_ext = _gather(params, f_inst, origin, ids, active)
            out, T_out, alpha, T_rel = fwd(pix, g, f_ext, T)
            out_t.index_add_(0, active, out)
            saved.append((active, ids, T, T_out, alpha, T_rel))
            j += chunk
            go_on = (counts[active] > j) & (T_out.amax(-1) > min_transmittance)
            if not bool(go_on.all()):
                stop = active[~go_on]
                T_t[stop] = T_out[~go_on]
                active, T_out = active[go_on], T_out[go_on]
            T = T_out
        if active.numel():
            T_t[active] = T
        ctx.saved = saved
        ctx.save_for_backward(params, f_inst, pix, origin)
        ctx.compile_ = compile_
        return out_t, T_t

    @staticmethod
    def backward(ctx, g_out_t, g_T_t):
        params, f_inst, pix, origin = ctx.saved_tensors
        _, bwd = _fns(ctx.compile_)
        g_out_t = g_out_t.contiguous() if g_out_t is not None else None
        gT = g_T_t.clone() if g_T_t is not None else None
        d_params = torch.zeros_like(params)
        d_f = torch.zeros_like(f_inst)
        for active, ids, T_in, T_out, alpha, T_rel in reversed(ctx.saved):
            g, f_ext = _gather(params, f_inst, origin, ids, active)
            go = (
                g_out_t.index_select(0, active)
                if g_out_t is not None
                else torch.zeros_like(f_ext[:, :1].expand(-1, pix.shape[0], -1))
            )
            gt = gT.index_select(0, active) if gT is not None else torch.zeros_like(T_in)
            d_g, d_fe, d_T_in = bwd(pix, g, f_ext, T_in, T_out, alpha, T_rel, go, gt)
            d_params.index_add_(0, ids.reshape(-1), d_g.reshape(-1, d_g.shape[-1]))
            d_f.index_add_(0, ids.reshape(-1), d_fe.reshape(-1, d_fe.shape[-1]))
            if gT is None:
                gT = torch.zeros(origin.shape[0], pix.shape[0], dtype=T_in.dtype, device=T_in.device)
            gT[active] = d_T_in
        return d_params, d_f, None, None, None, None, None, None, None


def composite_tiles(params, f_inst, table, counts, pix, origin, chunk=32, min_transmittance=1e-4, compile_=False):
    """Differentiable front-to-back compositing of every tile (see :class:`_CompositeTiles`).

    params: (M + 1, 6) packed (mx, my, a, b, c, opacity) per instance, row M the zero-opacity sentinel;
    f_inst: (M + 1, D) features (depth appended); table: (T, K_max) depth-ordered rows per tile, padded with M;
    counts: (T,); pix: (P, 2) tile-local pixel centres; origin: (T, 6) tile origins as parameter offsets.
    Returns per-tile features (T, P, D) and final transmittance (T, P).
    """
    return _CompositeTiles.apply(params, f_inst, table, counts, pix, origin, chunk, min_transmittance, compile_)


def bin_pairs(proj: Projected, height: int, width: int, tile: int, kernel: str = "torch"):
    """Instances and their (tile, depth)-sorted pairs.

    Returns ``inst`` (M,) flat (view * N + n) indices of valid instances in depth order, ``table``
    (T, K_max) long instance positions (into ``inst``; M = padding), ``counts`` (T,) pairs per tile, and the
    tile grid (TY, TX). ``kernel="native"`` (CPU) builds the table by a counting sort in C++
    (:func:`frng.render.native.bin_tiles`) and returns its rows concatenated, (sum(counts),) long (the same rows,
    bit for bit, without the padding, which :func:`frng.render.native.composite_tiles` reads).
    """
    V, N = proj.depth.shape
    TY, TX = -(-height // tile), -(-width // tile)
    dev = proj.depth.device
    with torch.no_grad():
        valid = proj.valid.reshape(-1)
        inst = valid.nonzero().squeeze(1)
        depth = proj.depth.reshape(-1)[inst]
        inst = inst[torch.argsort(depth, stable=True)]
        if kernel == "native":
            from frng.render import native

            table, counts = native.bin_tiles(proj.mean2d, proj.extent, inst, TY, TX, tile)
            return inst, table, counts, (TY, TX)
        M = inst.numel()
        m = proj.mean2d.detach().reshape(-1, 2)[inst]
        ext = proj.extent.reshape(-1, 2)[inst]
        x0 = torch.floor((m[:, 0] - ext[:, 0]) / tile).clamp(0, TX - 1).long()
        x1 = torch.floor((m[:, 0] + ext[:, 0]) / tile).clamp(0, TX - 1).long()
        y0 = torch.floor((m[:, 1] - ext[:, 1]) / tile).clamp(0, TY - 1).long()
        y1 = torch.floor((m[:, 1] + ext[:, 1]) / tile).clamp(0, TY - 1).long()
        nx = x1 - x0 + 1
        cnt = nx * (y1 - y0 + 1)
        rep = torch.repeat_interleave(torch.arange(M, device=dev), cnt)
        start = torch.cumsum(cnt, 0) - cnt
        local = torch.arange(rep.numel(), device=dev) - start[rep]
        nxr = nx[rep]
        tx = x0[rep] + local % nxr
        ty = y0[rep] + torch.div(local, nxr, rounding_mode="floor")
        view = torch.div(inst[rep], N, rounding_mode="floor")
        tile_id = (view * TY + ty) * TX + tx
        tile_sorted, order = torch.sort(tile_id, stable=True)  # stable: depth order within a tile
        pos_inst = rep[order]
        n_tiles = V * TY * TX
        counts = torch.bincount(tile_sorted, minlength=n_tiles)
        tstart = torch.cumsum(counts, 0) - counts
        slot = torch.arange(tile_sorted.numel(), device=dev) - tstart[tile_sorted]
        kmax = int(counts.max()) if counts.numel() and tile_sorted.numel() else 0
        table = torch.full((n_tiles, max(kmax, 1)), M, dtype=torch.long, device=dev)
        table[tile_sorted, slot] = pos_inst
    return inst, table, counts, (TY, TX)


def rasterize_tiles(
    proj: Projected,
    opacities: torch.Tensor,
    features: torch.Tensor,
    height: int,
    width: int,
    tile: int = 4,
    chunk: int = 64,
    min_transmittance: float = 1e-4,
    compile: bool = False,
    kernel: str = "torch",
):
    """Tile-binned compositing of projected Gaussians. Shapes as in :func:`frng.render.rasterize`;
    ``features`` is (N, C) or (V, N, C). ``kernel``: ``torch`` (:func:`composite_tiles`, any device) or
    ``native`` (CPU: the fused C++ compositing kernel :func:`frng.render.native.composite_tiles` and the C++
    table build of :func:`bin_pairs`; ``chunk`` and ``compile`` do not apply). Projection, the depth sort,
    packing and untiling are shared."""
    if kernel not in TILE_KERNELS:
        raise ValueError(f"unknown tile kernel {kernel!r}; choose from {', '.join(TILE_KERNELS)}")
    V, N = proj.depth.shape
    C = features.shape[-1]
    dev, dtype = features.device, features.dtype
    inst, table, counts, (TY, TX) = bin_pairs(proj, height, width, tile, kernel)
    n_tiles = V * TY * TX

    # per-instance parameters packed into (M + 1, 6) and features with depth appended into (M + 1, C + 1);
    # row M is the padding sentinel (opacity 0, so alpha = 0)
    gauss = inst % N
    params = torch.cat(
        [proj.mean2d.reshape(-1, 2)[inst], proj.conic.reshape(-1, 3)[inst], opacities.clamp(0.0, 1.0)[gauss, None]],
        dim=1,
    )
    params = torch.cat([params, params.new_zeros(1, 6)], dim=0)
    f_inst = features[gauss] if features.dim() == 2 else features.reshape(-1, C)[inst]
    f_inst = torch.cat([torch.cat([f_inst, proj.depth.reshape(-1, 1)[inst]], dim=1), f_inst.new_zeros(1, C + 1)])

    # tile-local pixel centres (P, 2) and tile origins as a (n_tiles, 6) offset for the packed parameters
    with torch.no_grad():
        ar = torch.arange(tile, device=dev, dtype=dtype)
        oy, ox = torch.meshgrid(ar, ar, indexing="ij")
        pix = torch.stack([ox.reshape(-1), oy.reshape(-1)], -1) + 0.5
        t_all = torch.arange(n_tiles, device=dev)
        origin = torch.zeros(n_tiles, 6, device=dev, dtype=dtype)
        origin[:, 0] = (t_all % TX).to(dtype) * tile
        origin[:, 1] = (torch.div(t_all, TX, rounding_mode="floor") % TY).to(dtype) * tile

    if kernel == "native":
        from frng.render import native

        feat_t, T_t = native.composite_tiles(params, f_inst, table, counts, pix, origin, min_transmittance)
    else:
        feat_t, T_t = composite_tiles(params, f_inst, table, counts, pix, origin, chunk, min_transmittance, compile)

    def untile(x):  # (n_tiles, P, D) -> (V, H, W, D)
        D = x.shape[-1]
        x = x.reshape(V, TY, TX, tile, tile, D).permute(0, 1, 3, 2, 4, 5).reshape(V, TY * tile, TX * tile, D)
        return x[:, :height, :width]

    img = untile(feat_t)
    return img[..., :C], untile(1.0 - T_t[..., None]), img[..., C:]
