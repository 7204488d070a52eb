"""frng.report.tables: best-value marking direction, Markdown shape, LaTeX booktabs structure, per-table helpers."""

import pandas as pd
import pytest

from frng.report import tables as T


def _ablation():
    return pd.DataFrame({
        "variant": ["full", "w/o fine-grained Gaussians", "w/o IDM priors"],
        "psnr": [32.44, 31.46, 31.21],
        "ssim": [0.947, 0.957, 0.945],
        "lpips": [0.049, 0.047, 0.043],
    })


def test_direction():
    assert T.direction("psnr") == "max" and T.direction("ssim") == "max" and T.direction("speedup") == "max"
    assert T.direction("lpips") == "min" and T.direction("reconstruction_s") == "min"
    assert T.direction("relight_ms_per_image") == "min"
    for c in ("views", "k_percent", "resolution", "spp", "variant", "n"):
        assert T.direction(c) is None


def test_best_marking_markdown_and_latex(tmp_path):
    out = T.write_table(_ablation(), tmp_path / "ablation", caption="aligned protocol", label="tab:ablation")
    assert set(out) == {"csv", "md", "tex"} and all(p.exists() for p in out.values())
    md = out["md"].read_text()
    lines = [l for l in md.splitlines() if l.startswith("|")]
    assert len(lines) == 2 + 3 and all(l.count("|") == 5 for l in lines)  # header, rule, 3 rows; 4 columns
    assert "**32.44**" in md and "**0.957**" in md and "**0.043**" in md  # psnr/ssim max, lpips min
    assert "**31.21**" not in md and "**0.049**" not in md
    tex = out["tex"].read_text()
    assert "\\definecolor{tabfirst}" in tex
    i_top, i_mid, i_bot = tex.index("\\toprule"), tex.index("\\midrule"), tex.index("\\bottomrule")
    assert i_top < i_mid < i_bot and tex.count("\\begin{tabular}{lccc}") == 1 and "\\end{tabular}" in tex
    assert tex.count("\\cellcolor{tabfirst}") == 3
    assert "\\cellcolor{tabfirst}{32.44}" in tex and "\\cellcolor{tabfirst}{0.043}" in tex
    body = tex[i_mid:i_bot].splitlines()[1:]
    assert all(l.endswith("\\\\") and l.count(" & ") == 3 for l in body)
    assert "w/o IDM priors" in tex and "\\caption{aligned protocol}" in tex
    csv = pd.read_csv(out["csv"])
    assert list(csv.columns) == ["variant", "psnr", "ssim", "lpips"] and len(csv) == 3


def test_ties_second_and_groups():
    df = pd.DataFrame({"dataset": ["a", "a", "a", "b", "b"], "method": ["x", "y", "z", "x", "y"],
                       "psnr": [30.001, 30.004, 29.0, 20.0, 25.0], "lpips": [0.1, 0.2, 0.3, 0.5, 0.4]})
    md, tex = T.render(df, best_within=["dataset"], second=True)
    assert md.count("**30.00**") == 2  # tie at displayed precision: both best
    assert "*29.00*" in md  # second-best distinct value
    assert "**25.00**" in md and "**20.00**" not in md  # best found per dataset
    assert "**0.400**" in md and "\\cellcolor{tabsecond}{0.200}" in tex


def test_vs_backbone_and_timing(tmp_path):
    m = pd.DataFrame({"dataset": ["objaverse", "objaverse"], "method": ["F-RNG", "backbone"],
                      "n": [10, 10], "psnr": [31.77, 30.02], "ssim": [0.945, 0.950], "lpips": [0.047, 0.049]})
    rows, footer = T.vs_backbone(m, {"F-RNG": 246.0, "backbone": 6826.0})
    out = T.write_table(rows, tmp_path / "vs_backbone.md", footer=footer, best_within=["dataset"])
    tex = out["tex"].read_text()
    assert tex.count("\\midrule") == 2 and "\\cellcolor{tabfirst}{246.0}" in tex
    assert "6826.0" in tex and "\\cellcolor{tabfirst}{6826.0}" not in tex
    assert len(pd.read_csv(out["csv"])) == 4
    t = T.timing(pd.DataFrame({"method": ["F-RNG", "backbone"], "reconstruction_s": [7.0, 5.0],
                               "relight_ms_per_image": [246.0, 6826.0], "resolution": [64, 64], "spp": [64, 64]}),
                 reference="backbone")
    assert t["speedup"].tolist() == pytest.approx([6826.0 / 246.0, 1.0])
    md, _ = T.render(t)
    assert "**27.7**" in md and "| 64 |" in md
