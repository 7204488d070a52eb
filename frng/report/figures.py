"""Figures: image grids, saliency overlays, loss curves (matplotlib Agg, written as PNG atomically).

Every function takes numpy arrays and labels (never file layouts) and writes one PNG. Images are linear
scene-referred by default -- (H, W, 3) RGB or (H, W, 4) premultiplied RGBA, which is composited over
``background`` -- and are tonemapped for display through :func:`frng.io.tonemap` (exposure, clip,
colour-science sRGB encoding). Pass ``encoded=True`` for images that are already display-encoded in [0, 1]
(e.g. a colour-mapped depth). A 2-D (H, W) image is shown as grey.

Grids are laid out in exact pixels: each image is drawn unresampled (``figimage``) into a cell of a fixed size
(nearest-neighbour integer upscaling by default, so 64 px renders stay crisp at 128 px), with row labels in a
left margin, column labels and an optional title in a top margin, and optional per-cell captions (e.g. PSNR)
in a box at the cell's bottom-left. The grid functions return the layout -- the PNG's pixel size and each
cell's pixel box -- so callers (and tests) know where everything is.

Only :class:`matplotlib.figure.Figure` with an explicit Agg canvas is used (no pyplot, no global backend change).
"""

from __future__ import annotations

import math
import os
import textwrap
from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np

from frng.io import atomic_path, composite, tonemap

DPI = 100
FONT_PX = 14  # label font height in pixels
PAD = 6  # pixels around labels and between cells
BLANK = 0.92  # grey of an empty cell
RECT_COLOUR = (0.0, 1.0, 0.35)  # selected-patch rectangles (display RGB)

Image = np.ndarray


# -- images -> display ----------------------------------------------------------------------------


def to_display(
    image: Image,
    exposure: float = 1.0,
    background: Sequence[float] = (1.0, 1.0, 1.0),
    encoded: bool = False,
) -> np.ndarray:
    """Any image -> display sRGB float32 (H, W, 3) in [0, 1].

    image: (H, W) grey, (H, W, 3) RGB or (H, W, 4) premultiplied RGBA (composited over ``background``, a
    linear colour). Linear images are tonemapped (``exposure`` then sRGB); ``encoded=True`` only clips.
    """
    img = np.asarray(image, dtype=np.float32)
    if img.ndim == 2:
        img = np.repeat(img[..., None], 3, axis=-1)
    if img.ndim != 3 or img.shape[-1] not in (1, 3, 4):
        raise ValueError(f"image must be (H, W), (H, W, 1|3|4); got {img.shape}")
    if img.shape[-1] == 1:
        img = np.repeat(img, 3, axis=-1)
    if img.shape[-1] == 4:
        bg = np.asarray(background, np.float32)
        if encoded:  # display-space alpha blend
            img = img[..., :3] + (1.0 - img[..., 3:4]) * bg
        else:
            img = composite(img, bg)
    img = np.nan_to_num(img, nan=0.0, posinf=1.0, neginf=0.0)
    return np.clip(img, 0.0, 1.0) if encoded else tonemap(img, exposure)


def fit_to_cell(display: np.ndarray, cell: tuple[int, int], fill: float = BLANK) -> np.ndarray:
    """Resize a display image (h, w, 3) into a cell (H, W), keeping its aspect ratio (letterboxed on ``fill``).

    Integer upscaling is nearest-neighbour (crisp pixels); other factors are bilinear (anti-aliased down).
    """
    H, W = cell
    h, w = display.shape[:2]
    s = min(H / h, W / w)
    nh, nw = max(1, round(h * s)), max(1, round(w * s))
    if (nh, nw) == (h, w):
        out = display
    elif nh % h == 0 and nw % w == 0 and nh // h == nw // w:
        k = nh // h
        out = np.repeat(np.repeat(display, k, axis=0), k, axis=1)
    else:
        from skimage.transform import resize

        out = resize(display, (nh, nw), order=1, anti_aliasing=(nh < h), preserve_range=True).astype(np.float32)
    if (nh, nw) == (H, W):
        return out
    canvas = np.full((H, W, 3), fill, np.float32)
    y0, x0 = (H - nh) // 2, (W - nw) // 2
    canvas[y0 : y0 + nh, x0 : x0 + nw] = out
    return canvas


def default_cell(shapes: Sequence[tuple[int, ...]], min_px: int = 128) -> tuple[int, int]:
    """Cell size for images of these shapes: the largest (H, W), upscaled by the smallest integer that makes
    its height at least ``min_px``."""
    if not shapes:
        raise ValueError("no images")
    h = max(s[0] for s in shapes)
    w = max(s[1] for s in shapes)
    k = max(1, math.ceil(min_px / h))
    return h * k, w * k


# -- the grid engine ------------------------------------------------------------------------------


def _wrap(label: str | None, chars: int) -> list[str]:
    if not label:
        return []
    lines = []
    for part in str(label).split("\n"):
        lines += textwrap.wrap(part, max(4, chars)) or [""]
    return lines


def _grid(
    out_png: str | os.PathLike,
    cells: Sequence[Sequence[np.ndarray | None]],
    cell: tuple[int, int],
    row_labels: Sequence[str | None] | None = None,
    col_labels: Sequence[str | None] | None = None,
    captions: Sequence[Sequence[str | None]] | None = None,
    title: str | None = None,
    font_px: int = FONT_PX,
    decorate=None,
) -> dict:
    """Lay out display tiles (each exactly ``cell`` (H, W, 3)) in a labelled grid and save a PNG.

    decorate(fig, layout): optional hook to draw extra artists (pixel boxes are in ``layout``).
    Returns {"path", "size": (width, height), "cells": [[(x0, y0, x1, y1) | None per column] per row]}, boxes in
    PNG pixels (x right, y down, half-open).
    """
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    nrows = len(cells)
    ncols = max((len(r) for r in cells), default=0)
    if nrows == 0 or ncols == 0:
        raise ValueError("empty grid")
    ch, cw = cell
    char_w = 0.6 * font_px
    line_h = int(round(1.3 * font_px))
    row_lines = [_wrap(l, 18) for l in (row_labels or [])]
    col_lines = [_wrap(l, int(cw // char_w)) for l in (col_labels or [])]
    title_lines = _wrap(title, 200)
    left = PAD + (
        int(max((max(len(s) for s in ls) for ls in row_lines if ls), default=0) * char_w) + PAD if any(row_lines) else 0
    )
    top = PAD + len(title_lines) * line_h + (PAD if title_lines else 0)
    top_cols = top
    top += max((len(ls) for ls in col_lines), default=0) * line_h + (PAD if any(col_lines) else 0)
    width = left + ncols * cw + (ncols - 1) * PAD + PAD
    height = top + nrows * ch + (nrows - 1) * PAD + PAD

    canvas = np.ones((height, width, 3), np.float32)
    boxes: list[list[tuple[int, int, int, int] | None]] = []
    for i, row in enumerate(cells):
        boxes.append([])
        for j in range(ncols):
            x0, y0 = left + j * (cw + PAD), top + i * (ch + PAD)
            tile = row[j] if j < len(row) else None
            if tile is None:
                boxes[-1].append(None)
                continue
            if tile.shape != (ch, cw, 3):
                raise ValueError(f"tile ({i}, {j}) has shape {tile.shape}, expected {(ch, cw, 3)}")
            canvas[y0 : y0 + ch, x0 : x0 + cw] = tile
            boxes[-1].append((x0, y0, x0 + cw, y0 + ch))

    fig = Figure(figsize=(width / DPI, height / DPI), dpi=DPI, facecolor="white")
    FigureCanvasAgg(fig)
    fig.figimage((np.clip(canvas, 0, 1) * 255 + 0.5).astype(np.uint8), 0, 0, origin="upper", resize=False)
    pt = font_px * 72.0 / DPI

    def text(x, y, s, **kw):  # pixel coordinates, y down
        return fig.text(x / width, 1.0 - y / height, s, fontsize=kw.pop("size", pt), **kw)

    if title_lines:
        text(width / 2, PAD, "\n".join(title_lines), ha="center", va="top", weight="bold")
    for j, ls in enumerate(col_lines):
        if ls:
            text(left + j * (cw + PAD) + cw / 2, top_cols, "\n".join(ls), ha="center", va="top")
    for i, ls in enumerate(row_lines):
        if ls:
            text(PAD, top + i * (ch + PAD) + ch / 2, "\n".join(ls), ha="left", va="center")
    if captions is not None:
        for i, row in enumerate(captions):
            for j, cap in enumerate(row or []):
                if cap is None or cap == "" or i >= nrows or j >= ncols or boxes[i][j] is None:
                    continue
                x0, y0, x1, y1 = boxes[i][j]
                text(
                    x0 + 3,
                    y1 - 3,
                    str(cap),
                    ha="left",
                    va="bottom",
                    color="white",
                    size=0.8 * pt,
                    bbox=dict(boxstyle="square,pad=0.15", facecolor="black", alpha=0.6, linewidth=0),
                )
    layout = {"path": str(out_png), "size": (width, height), "cells": boxes}
    if decorate is not None:
        decorate(fig, layout)
    with atomic_path(out_png) as tmp:
        fig.savefig(tmp, dpi=DPI, format="png", facecolor="white")
    return layout


def _caption(v) -> str | None:
    if v is None:
        return None
    if isinstance(v, (float, np.floating, int, np.integer)):
        return f"{float(v):.2f} dB"
    return str(v)


def _tiles(rows, exposure, background, encoded, cell, min_px):
    disp = [[None if im is None else to_display(im, exposure, background, encoded) for im in row] for row in rows]
    shapes = [d.shape for row in disp for d in row if d is not None]
    cell = default_cell(shapes, min_px) if cell is None else ((cell, cell) if isinstance(cell, int) else tuple(cell))
    return [[None if d is None else fit_to_cell(d, cell) for d in row] for row in disp], cell


# -- public figures -------------------------------------------------------------------------------


def comparison_grid(
    out_png: str | os.PathLike,
    rows: Sequence[Sequence[Image | None]],
    row_labels: Sequence[str | None] | None = None,
    col_labels: Sequence[str | None] | None = None,
    annotations: Sequence[Sequence[str | float | None]] | None = None,
    title: str | None = None,
    exposure: float = 1.0,
    background: Sequence[float] = (1.0, 1.0, 1.0),
    encoded: bool = False,
    cell: int | tuple[int, int] | None = None,
    min_cell_px: int = 128,
) -> dict:
    """A labelled grid of images, e.g. per test object: input views | ground truth | backbone | F-RNG, one row
    per test light.

    rows: R lists of images (any of :func:`to_display`'s shapes; None leaves a blank cell; rows may be short).
    row_labels (R,), col_labels (max row length,): text, None for none. annotations: R lists of per-cell
    captions; a number is shown as PSNR ("28.31 dB"), a string as is, None for none.
    cell: cell size in pixels (int = square, or (H, W)); default: the largest image upscaled by an integer to
    at least ``min_cell_px`` high. Returns the layout (see module docstring).
    """
    tiles, cell = _tiles(rows, exposure, background, encoded, cell, min_cell_px)
    caps = None if annotations is None else [[_caption(v) for v in row] for row in annotations]
    return _grid(out_png, tiles, cell, row_labels, col_labels, caps, title)


def object_comparison(
    out_png: str | os.PathLike,
    inputs: Sequence[Image],
    ground_truth: Sequence[Image],
    backbone: Sequence[Image],
    frng: Sequence[Image],
    light_labels: Sequence[str],
    envmaps: Sequence[Image] | None = None,
    psnr_backbone: Sequence[float] | None = None,
    psnr_frng: Sequence[float] | None = None,
    title: str | None = None,
    plus: Sequence[Image] | None = None,
    psnr_plus: Sequence[float] | None = None,
    **kwargs,
) -> dict:
    """The paper-style figure for one test object: columns input views | (light) | ground truth | backbone |
    F-RNG | (F-RNG+), one row per test light L.

    inputs: V input views, tiled into one mosaic cell in the first row. ground_truth, backbone, frng (and plus,
    F-RNG+, or None to omit that column): L images each, same view. envmaps: L equirect maps (linear, shown
    letterboxed) or None to omit that column. psnr_*: L values captioned on the backbone / F-RNG / F-RNG+ cells.
    kwargs go to :func:`comparison_grid`.
    """
    L = len(light_labels)
    methods = (("ground_truth", ground_truth), ("backbone", backbone), ("frng", frng))
    for name, seq in methods + ((("plus", plus),) if plus is not None else ()):
        if len(seq) != L:
            raise ValueError(f"{name} has {len(seq)} images for {L} lights")
    exposure = kwargs.get("exposure", 1.0)
    background = kwargs.get("background", (1.0, 1.0, 1.0))
    mosaic = mosaic_views([to_display(v, exposure, background) for v in inputs])
    rows, caps = [], []
    for i in range(L):
        row = [mosaic if i == 0 else None]
        if envmaps is not None:
            row.append(to_display(envmaps[i], exposure))
        row += [
            to_display(ground_truth[i], exposure, background),
            to_display(backbone[i], exposure, background),
            to_display(frng[i], exposure, background),
        ]
        if plus is not None:
            row.append(to_display(plus[i], exposure, background))
        rows.append(row)
        off = 2 if envmaps is not None else 1
        cap = [None] * (off + 3 + (plus is not None))
        cap[off + 1] = None if psnr_backbone is None else psnr_backbone[i]
        cap[off + 2] = None if psnr_frng is None else psnr_frng[i]
        if plus is not None:
            cap[off + 3] = None if psnr_plus is None else psnr_plus[i]
        caps.append(cap)
    cols = (
        [f"input views ({len(inputs)})"]
        + (["light"] if envmaps is not None else [])
        + ["ground truth", "backbone", "F-RNG"]
        + (["F-RNG+"] if plus is not None else [])
    )
    if kwargs.get("cell") is None:  # size cells for the renders; the input mosaic is fitted into one cell
        kwargs["cell"] = default_cell([np.shape(g) for g in ground_truth], kwargs.pop("min_cell_px", 128))
    kwargs = {**kwargs, "encoded": True, "exposure": 1.0}
    return comparison_grid(out_png, rows, list(light_labels), cols, caps, title, **kwargs)


def mosaic_views(displays: Sequence[np.ndarray], ncols: int | None = None) -> np.ndarray:
    """Tile display images (h, w, 3) (same size) into one image, ``ncols`` per row (default ceil(sqrt(V)))
    with a 1-pixel white gap. Returns (rows*h + gaps, ncols*w + gaps, 3)."""
    if not displays:
        raise ValueError("no views to tile")
    h, w = displays[0].shape[:2]
    n = len(displays)
    ncols = ncols or math.ceil(math.sqrt(n))
    nrows = math.ceil(n / ncols)
    out = np.ones((nrows * h + nrows - 1, ncols * w + ncols - 1, 3), np.float32)
    for k, d in enumerate(displays):
        if d.shape[:2] != (h, w):
            d = fit_to_cell(d, (h, w))
        r, c = divmod(k, ncols)
        out[r * (h + 1) : r * (h + 1) + h, c * (w + 1) : c * (w + 1) + w] = d
    return out


def ablation_grid(
    out_png: str | os.PathLike,
    variants: Mapping[str, Sequence[Image]],
    ground_truth: Sequence[Image] | None = None,
    row_labels: Sequence[str] | None = None,
    metrics: Mapping[str, Sequence[float | str]] | None = None,
    title: str | None = None,
    **kwargs,
) -> dict:
    """Ablation figure: columns ground truth (optional) then one per variant, one row per example (object/light).

    variants: variant name -> R images (all variants the same R). metrics: variant name -> R captions (numbers
    shown as PSNR). kwargs go to :func:`comparison_grid`.
    """
    names = list(variants)
    if not names:
        raise ValueError("ablation_grid needs at least one variant")
    R = len(variants[names[0]])
    for n in names:
        if len(variants[n]) != R:
            raise ValueError(f"variant {n!r} has {len(variants[n])} images, {names[0]!r} has {R}")
    if ground_truth is not None and len(ground_truth) != R:
        raise ValueError(f"ground_truth has {len(ground_truth)} images for {R} rows")
    gt = [] if ground_truth is None else [ground_truth]
    rows = [[g[r] for g in gt] + [variants[n][r] for n in names] for r in range(R)]
    caps = None
    if metrics:
        caps = [[None] * len(gt) + [None if n not in metrics else metrics[n][r] for n in names] for r in range(R)]
    cols = (["ground truth"] if gt else []) + names
    return comparison_grid(out_png, rows, row_labels, cols, caps, title, **kwargs)


def contact_sheet(
    out_png: str | os.PathLike,
    images: Sequence[Image] | Sequence[Sequence[Image | None]],
    ncols: int | None = None,
    captions: Sequence[str | None] | Sequence[Sequence[str | None]] | None = None,
    title: str | None = None,
    **kwargs,
) -> dict:
    """Many images at a glance. ``images`` is either a flat list (laid out ``ncols`` per row, default
    ceil(sqrt(n))) with a flat list of captions, or already a grid (list of rows) with a grid of captions.
    kwargs go to :func:`comparison_grid`."""
    images = list(images)
    flat = not images or not isinstance(images[0], (list, tuple))
    if flat:
        n = len(images)
        ncols = ncols or max(1, math.ceil(math.sqrt(n)))
        rows = [images[i : i + ncols] for i in range(0, n, ncols)]
        caps = None if captions is None else [list(captions)[i : i + ncols] for i in range(0, n, ncols)]
    else:
        rows, caps = images, captions
    return comparison_grid(out_png, rows, annotations=caps, title=title, **kwargs)


def saliency_panels(
    image: Image,
    saliency: np.ndarray,
    selected: np.ndarray,
    patch: int,
    scale: int = 1,
    alpha: float = 0.6,
    cmap: str = "inferno",
    exposure: float = 1.0,
    background: Sequence[float] = (1.0, 1.0, 1.0),
    encoded: bool = False,
    rect_colour: Sequence[float] = RECT_COLOUR,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The three display panels of a saliency figure, each (H*scale, W*scale, 3) float in [0, 1]:
    the image, the saliency heat map blended over it, the image with the selected patches outlined.

    image: (H, W[, C]) with H, W multiples of ``patch``. saliency: per patch (H/p, W/p) or per pixel (H, W);
    min-max normalised for display. selected: bool (H/p, W/p), True for the top-K patches. Rectangles are
    drawn inside each selected patch's pixel box, ``max(1, patch * scale // 10)`` px thick, in ``rect_colour``.
    """
    from matplotlib import colormaps

    disp = to_display(image, exposure, background, encoded)
    H, W = disp.shape[:2]
    if H % patch or W % patch:
        raise ValueError(f"image {H}x{W} is not a multiple of patch {patch}")
    hp, wp = H // patch, W // patch
    sel = np.asarray(selected).astype(bool)
    if sel.shape != (hp, wp):
        raise ValueError(f"selected mask must be ({hp}, {wp}) patches, got {sel.shape}")
    sal = np.asarray(saliency, np.float64)
    if sal.shape == (hp, wp):
        sal = np.repeat(np.repeat(sal, patch, 0), patch, 1)
    elif sal.shape != (H, W):
        raise ValueError(f"saliency must be ({hp}, {wp}) or ({H}, {W}), got {sal.shape}")
    sal = np.nan_to_num(sal)
    lo, hi = sal.min(), sal.max()
    sal = (sal - lo) / (hi - lo) if hi > lo else np.zeros_like(sal)
    heat = colormaps[cmap](sal)[..., :3].astype(np.float32)
    blend = (1 - alpha) * disp + alpha * heat
    up = lambda a: np.repeat(np.repeat(a, scale, 0), scale, 1)  # noqa: E731
    disp, blend = up(disp), up(blend)
    rects = disp.copy()
    ps = patch * scale
    t = max(1, ps // 10)
    colour = np.asarray(rect_colour, np.float32)
    for i, j in zip(*np.nonzero(sel)):
        y0, x0 = i * ps, j * ps
        box = rects[y0 : y0 + ps, x0 : x0 + ps]
        box[:t], box[-t:], box[:, :t], box[:, -t:] = colour, colour, colour, colour
    return disp, blend, rects


def saliency_overlay(
    out_png: str | os.PathLike,
    image: Image,
    saliency: np.ndarray,
    selected_patch_mask: np.ndarray,
    patch: int,
    title: str | None = None,
    scale: int | None = None,
    min_px: int = 192,
    **kwargs,
) -> dict:
    """Saliency figure for one view: image | saliency heat map | selected top-K patches (outlined).

    Shapes as :func:`saliency_panels` (kwargs go there). scale: integer upscaling (default: enough to make the
    image at least ``min_px`` high). Returns the grid layout; ``layout["scale"]`` is the upscaling used.
    """
    H = np.asarray(image).shape[0]
    scale = scale or max(1, math.ceil(min_px / H))
    panels = saliency_panels(image, saliency, selected_patch_mask, patch, scale=scale, **kwargs)
    k, total = int(np.count_nonzero(selected_patch_mask)), int(np.size(selected_patch_mask))
    cols = ["input", f"saliency ({kwargs.get('cmap', 'inferno')})", f"top-K patches: {k}/{total}"]
    layout = _grid(out_png, [list(panels)], panels[0].shape[:2], None, cols, None, title)
    layout["scale"] = scale
    return layout


def _ema(values: np.ndarray, smoothing: float) -> np.ndarray:
    """Debiased exponential moving average (TensorBoard's smoothing), NaNs skipped."""
    out = np.full(len(values), np.nan)
    acc, weight = 0.0, 0.0
    for i, v in enumerate(values):
        if np.isfinite(v):
            acc = smoothing * acc + (1 - smoothing) * v
            weight = smoothing * weight + (1 - smoothing)
        if weight > 0:
            out[i] = acc / weight
    return out


def loss_curves(
    sources,
    out_png: str | os.PathLike,
    x: str = "step",
    columns: Sequence[str] | None = None,
    smoothing: float = 0.9,
    logy: bool = True,
    title: str | None = None,
    panel_size: tuple[float, float] = (4.0, 3.0),
) -> Path:
    """Training curves: one panel per loss column, one colour per run; raw values faint, smoothed solid.

    sources: a CSV path or DataFrame, a list of them, or a mapping run label -> path/DataFrame (labels default
    to the file stem or "run i"). Each table has an ``x`` column (default "step"; the row index if absent) and
    numeric loss columns. columns: which to plot (default every numeric column but ``x`` found in any run,
    columns named like "epoch"/"time"/"lr" skipped). smoothing: EMA factor in [0, 1). logy: log y axis
    (non-positive values are dropped from that panel; a panel with none left positive stays linear).
    """
    import pandas as pd
    from matplotlib import colormaps
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    if isinstance(sources, (str, os.PathLike, pd.DataFrame)):
        sources = [sources]
    if not isinstance(sources, Mapping):
        labelled = {}
        for i, s in enumerate(sources):
            label = Path(s).stem if isinstance(s, (str, os.PathLike)) else f"run {i}"
            while label in labelled:
                label += "'"
            labelled[label] = s
        sources = labelled
    runs = {}
    for label, s in sources.items():
        if isinstance(s, (str, os.PathLike)):
            if not Path(s).exists():
                raise FileNotFoundError(f"{s}: loss CSV does not exist")
            s = pd.read_csv(s)
        runs[label] = s
    if not runs:
        raise ValueError("loss_curves needs at least one run")
    skip = {x, "epoch", "time", "wall_s", "lr", "elapsed_s"}
    if columns is None:
        columns = []
        for df in runs.values():
            for c in df.select_dtypes("number").columns:
                if c not in skip and c not in columns:
                    columns.append(c)
    if not columns:
        raise ValueError(f"no numeric loss columns besides {x!r} in {list(runs)}")

    n = len(columns)
    ncols = min(n, 3)
    nrows = math.ceil(n / ncols)
    spare = nrows * ncols > n  # an empty panel holds the legend; else it goes below the panels
    legend_rows = 0 if spare or len(runs) < 2 else math.ceil(len(runs) / (2 * ncols))
    height = panel_size[1] * nrows + (0.4 if title else 0) + 0.25 * legend_rows
    fig = Figure(figsize=(panel_size[0] * ncols, height), dpi=DPI, layout="constrained")
    FigureCanvasAgg(fig)
    axes = fig.subplots(nrows, ncols, squeeze=False)
    # one colour per run: tab10's, or past ten runs tab20's (its dark shades first): no two runs share one
    palette = (
        [f"C{i}" for i in range(10)]
        if len(runs) <= 10
        else [colormaps["tab20"](i) for i in [*range(0, 20, 2), *range(1, 20, 2)]]
    )
    colours = [palette[i % len(palette)] for i in range(len(runs))]
    handles = {}
    for k, col in enumerate(columns):
        ax = axes[k // ncols][k % ncols]
        positive_any = False
        for (label, df), colour in zip(runs.items(), colours):
            if col not in df:
                continue
            xs = df[x].to_numpy(float) if x in df else np.arange(len(df), dtype=float)
            ys = df[col].to_numpy(float)
            if logy:
                ys = np.where(ys > 0, ys, np.nan)
                positive_any |= bool(np.isfinite(ys).any())
            ax.plot(xs, ys, color=colour, alpha=0.25, linewidth=0.8)
            (handles[label],) = ax.plot(xs, _ema(ys, smoothing), color=colour, linewidth=1.6, label=label)
        if logy and positive_any:
            ax.set_yscale("log")
        ax.set_title(col)
        ax.set_xlabel(x)
        ax.grid(True, which="both", alpha=0.3)
    for k in range(n, nrows * ncols):
        axes[k // ncols][k % ncols].set_axis_off()
    if len(runs) > 1:  # one legend for every panel, off the curves
        labels = [label for label in runs if label in handles]
        if spare:
            axes[n // ncols][n % ncols].legend([handles[k] for k in labels], labels, loc="center", fontsize=8)
        else:
            fig.legend([handles[k] for k in labels], labels, loc="outside lower center", ncol=2 * ncols, fontsize=8)
    if title:
        fig.suptitle(title)
    with atomic_path(out_png) as tmp:
        fig.savefig(tmp, dpi=DPI, format="png", facecolor="white")
    return Path(out_png)


__all__ = [
    "ablation_grid",
    "comparison_grid",
    "contact_sheet",
    "default_cell",
    "fit_to_cell",
    "loss_curves",
    "mosaic_views",
    "object_comparison",
    "saliency_overlay",
    "saliency_panels",
    "to_display",
]
