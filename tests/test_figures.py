"""Figure helpers (frng.report.figures): exact grid layout, labels drawn, saliency rectangles, loss curves from CSV."""

import numpy as np
import pandas as pd
import pytest

from frng.io import read_png, tonemap
from frng.report import figures as F


def _disc(h=32, w=32, colour=(0.8, 0.3, 0.1)):
    yy, xx = np.mgrid[:h, :w]
    a = (((yy - h / 2) ** 2 + (xx - w / 2) ** 2) < (0.4 * h) ** 2).astype(np.float32)
    rgb = np.asarray(colour, np.float32) * a[..., None] * (xx / w)[..., None]
    return np.concatenate([rgb, a[..., None]], -1)  # premultiplied RGBA, linear


def _dark(region):
    return int((region[..., :3].mean(-1) < 0.5).sum())


def test_comparison_grid_layout_and_labels(tmp_path):
    img = _disc()
    rows = [[img, img, img], [img, None, img]]
    out = tmp_path / "grid.png"
    lay = F.comparison_grid(
        out,
        rows,
        row_labels=["light 0", "light 1"],
        col_labels=["ground truth", "backbone", "F-RNG"],
        annotations=[[None, 24.5, 27.25], [None, None, "x"]],
        title="object 7",
        min_cell_px=64,
    )
    png = read_png(out)
    W, H = lay["size"]
    assert png.shape[:2] == (H, W)
    x0, y0, x1, y1 = lay["cells"][0][0]
    assert (x1 - x0, y1 - y0) == (64, 64)  # 32 px upscaled x2 to reach 64
    # the cell holds the tonemapped image composited on white, upscaled nearest-neighbour, unresampled
    expect = tonemap(img[..., :3] + (1 - img[..., 3:]))
    expect = np.repeat(np.repeat(expect, 2, 0), 2, 1)
    np.testing.assert_allclose(png[y0:y1, x0:x1, :3], expect, atol=1 / 255 + 1e-6)
    assert lay["cells"][1][1] is None
    # labels are drawn: dark pixels left of the first column (row labels) and above the first row (column labels)
    assert _dark(png[y0:y1, :x0]) > 20
    assert _dark(png[:y0, x0:x1]) > 20
    # an empty cell stays white
    bx0 = lay["cells"][0][1][0]
    assert png[lay["cells"][1][0][1] : lay["cells"][1][0][3], bx0 : bx0 + 64].min() > 0.99
    # the PSNR caption box (dark) sits at the bottom-left of the annotated cell
    cx0, cy0, cx1, cy1 = lay["cells"][0][1]
    assert _dark(png[cy1 - 14 : cy1, cx0 : cx0 + 50]) > 100


def test_ablation_grid_and_contact_sheet(tmp_path):
    img = _disc()
    lay = F.ablation_grid(
        tmp_path / "abl.png",
        {"full": [img, img], "w/o IDM priors": [img, img]},
        ground_truth=[img, img],
        row_labels=["a", "b"],
        metrics={"full": [27.0, 26.0]},
        cell=48,
    )
    assert len(lay["cells"]) == 2 and len(lay["cells"][0]) == 3
    assert read_png(tmp_path / "abl.png").shape[:2] == lay["size"][::-1]
    x0, y0, x1, y1 = lay["cells"][0][0]
    assert (x1 - x0, y1 - y0) == (48, 48)
    lay = F.contact_sheet(tmp_path / "sheet.png", [img] * 5, captions=[f"v{i}" for i in range(5)], cell=32)
    assert [len(r) for r in lay["cells"]] == [3, 3] and lay["cells"][1][2] is None
    with pytest.raises(ValueError, match="variant 'b' has 1 images"):
        F.ablation_grid(tmp_path / "x.png", {"a": [img, img], "b": [img]})


def test_object_comparison(tmp_path):
    img = _disc()
    env = np.ones((16, 32, 3), np.float32)
    lay = F.object_comparison(
        tmp_path / "obj.png",
        [img] * 6,
        [img] * 2,
        [img] * 2,
        [img] * 2,
        ["l0", "l1"],
        envmaps=[env, env],
        psnr_backbone=[20.0, 21.0],
        psnr_frng=[25.0, 26.0],
        min_cell_px=64,
    )
    assert [len(r) for r in lay["cells"]] == [5, 5]
    assert lay["cells"][1][0] is None  # the input mosaic only in the first row
    assert read_png(tmp_path / "obj.png").shape[:2] == lay["size"][::-1]


def test_saliency_overlay_rectangles(tmp_path):
    patch, scale = 8, 4
    img = np.full((32, 48, 3), 0.18, np.float32)  # 4 x 6 patches, uniform grey
    sal = np.random.default_rng(0).random((4, 6))
    sel = np.zeros((4, 6), bool)
    sel[1, 2] = sel[3, 5] = True
    lay = F.saliency_overlay(tmp_path / "sal.png", img, sal, sel, patch, scale=scale)
    png = read_png(tmp_path / "sal.png")[..., :3]
    assert png.shape[:2] == lay["size"][::-1] and lay["scale"] == scale
    x0, y0, x1, y1 = lay["cells"][0][2]  # the rectangles panel
    panel = png[y0:y1, x0:x1]
    assert panel.shape[:2] == (32 * scale, 48 * scale)
    green = (panel[..., 1] > 0.9) & (panel[..., 0] < 0.1)
    ps, t = patch * scale, max(1, patch * scale // 10)
    for i, j in [(1, 2), (3, 5)]:
        box = green[i * ps : (i + 1) * ps, j * ps : (j + 1) * ps]
        assert box[:t].all() and box[-t:].all() and box[:, :t].all() and box[:, -t:].all()  # full outline
        assert not box[t:-t, t:-t].any()  # interior untouched
    n_sel = sel.sum()
    assert green.sum() == n_sel * (ps * ps - (ps - 2 * t) ** 2)  # nothing outside the selected patches
    # the heat-map panel differs from the plain image; per-pixel saliency accepted too
    hx0, hy0, hx1, hy1 = lay["cells"][0][1]
    assert np.abs(png[hy0:hy1, hx0:hx1] - png[y0:y1, lay["cells"][0][0][0] : lay["cells"][0][0][2]]).max() > 0.1
    F.saliency_overlay(tmp_path / "sal2.png", img, np.random.default_rng(1).random((32, 48)), sel, patch, scale=1)
    with pytest.raises(ValueError, match=r"selected mask must be \(4, 6\)"):
        F.saliency_panels(img, sal, sel[:2], patch)


def test_loss_curves_from_csv(tmp_path):
    steps = np.arange(200)
    df = pd.DataFrame({"step": steps, "loss": np.exp(-steps / 50) + 0.01, "l2": np.exp(-steps / 80), "lr": 1e-4})
    csv = tmp_path / "train.csv"
    df.to_csv(csv, index=False)
    out = F.loss_curves([csv, df.assign(loss=df.loss * 2)], tmp_path / "loss.png", title="training")
    png = read_png(out)
    assert png.shape[0] > 200 and png.shape[1] > 500  # two panels (loss, l2; lr skipped) side by side
    assert (png[..., :3] < 0.9).any()
    with pytest.raises(FileNotFoundError, match="missing.csv"):
        F.loss_curves(tmp_path / "missing.csv", tmp_path / "x.png")
    np.testing.assert_allclose(F._ema(np.array([1.0, 1.0, np.nan, 1.0]), 0.9), [1, 1, 1, 1])
