"""One PNG contact sheet per curated object, for people to look at (stage :mod:`frng.stages.dataset_preview`,
``frng dataset-preview``).

Sheet layout (cells of ``--cell`` px; at most ``--max-views`` columns and ``--max-lights`` rows per block):

    inputs  : one row per input light,  one column per input view (in_00 ..)
    targets : one row per target light, one column per target view (tgt_000 ..)
    G-buffer of the input views: albedo, normal (n * 0.5 + 0.5), depth (near = bright), roughness, metallic

Renders are composited over a grey background and sRGB-encoded with colour-science (frng.io.tonemap).
Output: ``{results}/previews/{obj}.png``.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from frng import io
from frng.data.dataset import ObjectData
from frng.plan.layout import Layout

BACKGROUND = (0.18, 0.18, 0.18)  # linear grey behind the renders
LABEL_W = 150


def _fit(img: np.ndarray, cell: int) -> np.ndarray:
    """(H, W, C) -> (cell, cell, C): nearest-neighbour up-scaling, anti-aliased down-scaling."""
    h = img.shape[0]
    if h == cell:
        return img
    if cell % h == 0:
        k = cell // h
        return np.repeat(np.repeat(img, k, 0), k, 1)
    from skimage.transform import resize

    return resize(
        img, (cell, cell, img.shape[-1]), order=0 if cell > h else 1, anti_aliasing=cell < h, preserve_range=True
    ).astype(np.float32)


def _row(cells: list[np.ndarray], n_cols: int, cell: int) -> np.ndarray:
    row = np.full((cell, n_cols * cell, 3), 0.1, np.float32)  # empty cells: the label colour
    for i, c in enumerate(cells[:n_cols]):
        row[:, i * cell : (i + 1) * cell] = _fit(c, cell)[..., :3]
    return row


def _rgb(rgba: np.ndarray) -> np.ndarray:
    return io.tonemap(io.composite(rgba, BACKGROUND))


def _gbuffer_rows(gb: dict) -> list[tuple[str, list[np.ndarray]]]:
    a = gb["alpha"]
    bg = np.asarray(BACKGROUND, np.float32)
    over = lambda x: x * a + (1 - a) * io.srgb_encode(bg)  # noqa: E731  (display-space values over grey)
    depth = gb["depth"]
    hit = depth > 0
    near, far = (depth[hit].min(), depth[hit].max()) if hit.any() else (0.0, 1.0)
    d = np.where(hit, 1.0 - 0.8 * (depth - near) / max(far - near, 1e-6), 0.0)
    rows = [
        ("albedo", over(io.srgb_encode(gb["albedo"]))),
        ("normal", over(gb["normal"] * 0.5 + 0.5)),
        ("depth", over(np.repeat(d, 3, -1))),
        ("roughness", over(np.repeat(gb["roughness"], 3, -1))),
        ("metallic", over(np.repeat(gb["metallic"], 3, -1))),
    ]
    return [(name, list(x)) for name, x in rows]


def contact_sheet(obj: ObjectData, cell: int = 128, max_views: int = 10, max_lights: int = 6) -> np.ndarray:
    """The sheet as a display-encoded float image (H, W, 3) in [0, 1]."""
    in_views = obj.view_names("inputs")[:max_views]
    tg_views = obj.view_names("targets")[:max_views]
    n_cols = max(len(in_views), len(tg_views))
    rows: list[tuple[str, np.ndarray]] = []
    for light in obj.input_lights[:max_lights]:
        rows.append((f"in: {light}", _row(list(map(_rgb, obj.images("inputs", light, in_views))), n_cols, cell)))
    for light in obj.target_lights[:max_lights]:
        rows.append((f"tgt: {light}", _row(list(map(_rgb, obj.images("targets", light, tg_views))), n_cols, cell)))
    for name, cells in _gbuffer_rows(obj.gbuffer("inputs", in_views)):
        rows.append((name, _row(cells, n_cols, cell)))
    sheet = np.concatenate([r for _, r in rows], 0)
    labels = np.full((sheet.shape[0], LABEL_W, 3), 0.1, np.float32)
    sheet = np.concatenate([labels, sheet], 1)
    header = np.full((22, sheet.shape[1], 3), 0.1, np.float32)
    sheet = np.concatenate([header, sheet], 0)
    return _draw_labels(
        sheet,
        [n for n, _ in rows],
        cell,
        f"{obj.id} [{obj.split}] {obj.meta['material_class']} {obj.meta['source']}:{Path(obj.meta['mesh']).name}",
    )


def _draw_labels(sheet: np.ndarray, names: list[str], cell: int, title: str) -> np.ndarray:
    from PIL import Image, ImageDraw

    img = Image.fromarray((np.clip(sheet, 0, 1) * 255 + 0.5).astype(np.uint8))
    draw = ImageDraw.Draw(img)
    draw.text((4, 4), title, fill=(255, 255, 255))
    for i, name in enumerate(names):
        draw.text((4, 22 + i * cell + cell // 2 - 6), name[:24], fill=(230, 230, 230))
    return np.asarray(img).astype(np.float32) / 255.0


def write_previews(
    results: str | Path, objects: list[str], out: Path, cell: int, max_views: int, max_lights: int, log=print
) -> list[Path]:
    """One contact sheet per curated object of ``objects`` (under ``results``) into ``out/{obj}.png``."""
    L = Layout(results)
    paths = []
    for oid in objects:
        obj = ObjectData.open(L.object_dir(oid))
        path = out / f"{oid}.png"
        io.write_png(path, contact_sheet(obj, cell, max_views, max_lights))
        log(f"[preview] {path}")
        paths.append(path)
    return paths
