"""frng.report.tables: best-value marking direction, Markdown shape, LaTeX booktabs structure, per-table helpers."""

import numpy as np
import pandas as pd
import pytest

from frng.report import tables as T


def _ablation():
    return pd.DataFrame(
        {
            "variant": ["full", "w/o fine-grained Gaussians", "w/o IDM priors"],
            "psnr": [32.44, 31.46, 31.21],
            "ssim": [0.947, 0.957, 0.945],
            "lpips": [0.049, 0.047, 0.043],
        }
    )


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
    df = pd.DataFrame(
        {
            "dataset": ["a", "a", "a", "b", "b"],
            "method": ["x", "y", "z", "x", "y"],
            "psnr": [30.001, 30.004, 29.0, 20.0, 25.0],
            "lpips": [0.1, 0.2, 0.3, 0.5, 0.4],
        }
    )
    md, tex = T.render(df, best_within=["dataset"], second=True)
    assert md.count("**30.00**") == 2  # tie at displayed precision: both best
    assert "*29.00*" in md  # second-best distinct value
    assert "**25.00**" in md and "**20.00**" not in md  # best found per dataset
    assert "**0.400**" in md and "\\cellcolor{tabsecond}{0.200}" in tex


def test_vs_backbone_and_timing(tmp_path):
    m = pd.DataFrame(
        {
            "dataset": ["objaverse", "objaverse"],
            "method": ["F-RNG", "backbone"],
            "n": [10, 10],
            "psnr": [31.77, 30.02],
            "ssim": [0.945, 0.950],
            "lpips": [0.047, 0.049],
        }
    )
    rows, footer = T.vs_backbone(m, {"F-RNG": 246.0, "backbone": 6826.0})
    out = T.write_table(rows, tmp_path / "vs_backbone.md", footer=footer, best_within=["dataset"])
    tex = out["tex"].read_text()
    assert tex.count("\\midrule") == 2 and "\\cellcolor{tabfirst}{246.0}" in tex
    assert "6826.0" in tex and "\\cellcolor{tabfirst}{6826.0}" not in tex
    assert len(pd.read_csv(out["csv"])) == 4
    t = T.timing(
        pd.DataFrame(
            {
                "method": ["F-RNG", "backbone"],
                "reconstruction_s": [7.0, 5.0],
                "relight_ms_per_image": [246.0, 6826.0],
                "resolution": [64, 64],
                "spp": [64, 64],
            }
        ),
        reference="backbone",
    )
    assert t["speedup"].tolist() == pytest.approx([6826.0 / 246.0, 1.0])
    md, _ = T.render(t)
    assert "**27.7**" in md and "| 64 |" in md


def test_intervals_render_as_one_cell(tmp_path):
    df = pd.DataFrame(
        {
            "variant": ["full", "w/o fine"],
            "psnr": [18.72, 18.38],
            "dpsnr": [float("nan"), -0.3412],
            "dpsnr_lo": [float("nan"), -0.5801],
            "dpsnr_hi": [float("nan"), -0.2549],
            "dlpips": [float("nan"), 0.00234],
            "dlpips_lo": [float("nan"), 0.0011],
            "dlpips_hi": [float("nan"), 0.0036],
            "better": [float("nan"), 0.0],
            "objects": [float("nan"), 16.0],
        }
    )
    out = T.write_table(df, tmp_path / "t")
    md, tex = out["md"].read_text(), out["tex"].read_text()
    assert "| w/o fine | 18.38 | -0.34 [-0.58, -0.25] | +0.0023 [0.0011, 0.0036] | 0/16 |" in md
    assert (
        "ΔPSNR [95% CI]" in md
        and "_lo" not in md
        and "objects" not in md.split("\n")[0].replace("objects higher PSNR", "")
    )
    assert "$\\Delta$PSNR [95\\% CI]" in tex and "-0.34 [-0.58, -0.25]" in tex and "0/16" in tex
    assert tex.count("\\begin{tabular}{lcccc}") == 1  # variant, psnr, dpsnr, dlpips, better
    csv = pd.read_csv(out["csv"])
    assert list(csv.columns) == list(df.columns) and csv["dpsnr_lo"].iloc[1] == -0.5801  # unrounded


def _timing_file(path):
    """A relight timing JSON (frng relight's ``timing/{obj}.json``) at ``path``: F-RNG 20 ms, the backbone 40 ms."""
    from frng import io

    io.write_json(
        path,
        {
            "device": "cpu",
            "resolution": 32,
            "spp": 16,
            "F-RNG": {"reconstruction_s": 1.0, "relight_ms_per_image": 20.0},
            "backbone": {"reconstruction_s": 1.0, "relight_ms_per_image": 40.0},
        },
    )
    return path


def _per_image(run, variant, shift, seed_shift=0.0, objects=("o0", "o1", "o2"), dataset="diffuse"):
    return [
        dict(
            dataset=dataset,
            object=o,
            run=run,
            method="backbone" if run == "backbone" else "F-RNG",
            variant=variant,
            views=6,
            k=8.0,
            light=l,
            view="v0",
            protocol="aligned",
            psnr=17.0 + shift + seed_shift + 0.5 * j + 0.25 * i,
            ssim=0.5 + 0.01 * shift,
            lpips=0.1 - 0.01 * shift,
        )
        for j, o in enumerate(objects)
        for i, l in enumerate(("l0", "l1"))
    ]


def test_vs_backbone_and_ablation_average_seeds_and_report_intervals():
    from frng.report.paper_tables import ablation_table, vs_backbone_table

    rows = (
        _per_image("backbone", "backbone", 0.0)
        + _per_image("full", "full", 1.0)
        + _per_image("full@s1", "full@s1", 1.0, seed_shift=0.2)
        + _per_image("no-fine", "no-fine", 0.7)
        + _per_image("no-fine@s1", "no-fine@s1", 0.7, seed_shift=-0.2)
    )
    df = pd.DataFrame(rows)
    timing = [{"F-RNG": {"relight_ms_per_image": 20.0}, "backbone": {"relight_ms_per_image": 40.0}}]
    vs, footer = vs_backbone_table(df, timing)
    assert list(vs["dataset"]) == ["diffuse", "diffuse", "all", "all"]
    assert list(vs["method"]) == ["F-RNG (ours)", "backbone (RelitLRM-style)"] * 2
    f = vs.iloc[0]
    # F-RNG = mean of seeds 0 (+1.0) and 1 (+1.2) -> +1.1 over the backbone on every image
    assert np.isclose(f["psnr"] - vs.iloc[1]["psnr"], 1.1) and np.isclose(f["dpsnr"], 1.1)
    # the interval resamples F-RNG's two seeds too: all-s0 draws give +1.0, all-s1 +1.2 (p = 1/4 each)
    assert np.isclose(f["dpsnr_lo"], 1.0) and np.isclose(f["dpsnr_hi"], 1.2) and f["better"] == 3
    assert f["seeds"] == 2 and np.isclose(f["seed_spread_psnr"], 0.2) and np.isclose(f["seed_spread_dpsnr"], 0.2)
    assert pd.isna(vs.iloc[1]["dpsnr"]) and len(footer) == 2
    ab = ablation_table(df).set_index("variant")
    nf = ab.loc["w/o fine-grained Gaussians"]
    # no-fine seeds: +0.7, +0.5 -> 0.6; full: 1.1 -> -0.5; per seed: -0.3 (s0), -0.7 (s1) -> spread 0.4
    assert np.isclose(nf["dpsnr"], -0.5) and np.isclose(nf["seed_spread_dpsnr"], 0.4) and nf["better"] == 0
    # seed draws: no-fine in {0.7, 0.6, 0.5}, full in {1.0, 1.1, 1.2}; the extremes -0.7 / -0.3 have p = 1/16
    assert np.isclose(nf["dpsnr_lo"], -0.7) and np.isclose(nf["dpsnr_hi"], -0.3)
    assert np.isclose(ab.loc["full model", "seed_spread_psnr"], 0.2) and pd.isna(ab.loc["full model", "dpsnr"])
    assert list(ab.index) == ["full model", "w/o fine-grained Gaussians"]


def test_sweep_tables_compare_with_the_reference_row():
    from frng.report.paper_tables import k_table, views_table

    rows = _per_image("full", "full", 1.0) + _per_image("full@s1", "full@s1", 5.0)
    rows += [dict(r, run="full-v4", views=4) for r in _per_image("full-v4", "full", -2.0)]
    rows += [dict(r, k=2.0) for r in _per_image("k2", "k2", 0.5)]
    rows += _per_image("plus-base", "plus", -3.0)  # the Lambertian-base run is in no sweep
    df = pd.DataFrame(rows)
    v = views_table(df).set_index("views")
    assert list(v.index) == [4, 6] and np.isclose(v.loc[4, "dpsnr"], -3.0) and pd.isna(v.loc[6, "dpsnr"])
    assert np.isclose(v.loc[6, "psnr"], 18.0 + 0.5 + 0.125)  # the models' own seed only
    k = k_table(df).set_index("k_percent")
    assert list(k.index) == [2.0, 8.0] and np.isclose(k.loc[2.0, "dpsnr"], -0.5) and pd.isna(k.loc[8.0, "dpsnr"])
    assert np.isclose(k.loc[2.0, "dpsnr_lo"], -0.5) and np.isclose(k.loc[2.0, "dlpips"], 0.005)


def test_unmarked_footer():
    df = pd.DataFrame({"step": ["d", "e"], "psnr": [17.0, 18.0]})
    foot = pd.DataFrame({"step": ["s1", "s3"], "psnr": [16.0, 22.0]})
    md, tex = T.render(df, footer=foot, footer_best=False)
    assert "**18.00**" in md and "**22.00**" not in md and "| s3 | 22.00 |" in md
    assert "\\cellcolor{tabfirst}{22.00}" not in tex


def test_markdown_escapes_pipes_in_headers_and_cells():
    md, tex = T.render(pd.DataFrame({"what": ["a|b"], "scale_log2": [0.25]}))
    header = md.splitlines()[0]
    assert "median \\|log2 scale\\|" in header and header.count(" | ") == 1
    assert "| a\\|b | 0.25 |" in md and "a|b" in tex


def test_tables_per_light_family(tmp_path):
    """vs_backbone / ablation / ladder per family of the target light: the family from the plan's map (a mapping,
    not the light's name), rows per family, the paired differences and intervals within each family; written by
    write_tables beside the other tables."""
    from frng.report import paper_tables as P

    families = {"l0": "sky", "l1": "studio"}  # the plan's light -> family (Catalog.light_families)
    rows = _per_image("backbone", "backbone", 0.0) + _per_image("no-fine", "no-fine", 0.7)
    rows += [dict(r, psnr=r["psnr"] + (0.5 if r["light"] == "l1" else 0.0)) for r in _per_image("full", "full", 1.0)]
    df = P.with_families(pd.DataFrame(rows), families)
    vs = P.vs_backbone_by_light(df)
    cols = list(T.TABLE_COLUMNS["vs_backbone_by_light"])
    assert list(vs.columns[: len(cols)]) == cols
    assert list(vs["light_family"]) == ["sky", "sky", "studio", "studio"]
    assert list(vs["method"]) == ["F-RNG (ours)", "backbone (RelitLRM-style)"] * 2
    sky, studio = vs.iloc[0], vs.iloc[2]
    # F-RNG is +1.0 over the backbone under the sky, +1.5 under the studio, on every object
    assert np.isclose(sky["dpsnr"], 1.0) and np.isclose(sky["dpsnr_lo"], 1.0) and np.isclose(sky["dpsnr_hi"], 1.0)
    assert np.isclose(studio["dpsnr"], 1.5) and studio["better"] == 3 and studio["objects"] == 3
    assert sky["n"] == 3 and pd.isna(vs.iloc[1]["dpsnr"])
    ab = P.ablation_by_light(df)
    cols = list(T.TABLE_COLUMNS["ablation_by_light"])
    assert list(ab.columns[: len(cols)]) == cols
    assert list(zip(ab["light_family"], ab["variant"])) == [
        ("sky", "full model"),
        ("sky", "w/o fine-grained Gaussians"),
        ("studio", "full model"),
        ("studio", "w/o fine-grained Gaussians"),
    ]
    assert np.isclose(ab.iloc[1]["dpsnr"], -0.3) and np.isclose(ab.iloc[3]["dpsnr"], -0.8)
    prior = pd.DataFrame([dict(r, task="relight", method="gt-depth+oracle-colour") for r in _per_image("x", "x", 3.0)])
    lad = P.ladder_by_light(df, P.with_families(prior, families))
    assert list(lad.columns[: len(T.TABLE_COLUMNS["ladder_by_light"])]) == list(T.TABLE_COLUMNS["ladder_by_light"])
    assert set(lad["light_family"]) == {"sky", "studio"}
    assert list(lad[lad["light_family"] == "sky"]["step"]) == ["a", "d", "e"]  # the prior's rows by family too
    e = lad[(lad["step"] == "e") & (lad["light_family"] == "studio")].iloc[0]
    assert e["vs"] == "d" and np.isclose(e["dpsnr"], 1.5)
    assert P.with_families(pd.DataFrame({"light": ["zz"]}), families)["light_family"].tolist() == ["other"]

    # end to end: write_tables writes the three tables beside the others, with their columns
    per_image = tmp_path / "per_image.csv"
    pd.DataFrame(rows).to_csv(per_image, index=False)
    prior_csv = tmp_path / "backbone.csv"
    prior.to_csv(prior_csv, index=False)
    timing = _timing_file(tmp_path / "t.json")
    out = P.write_tables(
        "custom",
        [1, 1, 1],
        per_image,
        [timing],
        tmp_path / "tables",
        prior_csv,
        families=families,
        sources={"o0": "procedural", "o1": "libero", "o2": "libero"},
    )
    assert "object source" in out["vs_backbone_by_source"]["md"].read_text().lower()
    for name in ("vs_backbone_by_light", "ablation_by_light", "ladder_by_light"):
        t = pd.read_csv(out[name]["csv"])
        assert set(T.TABLE_COLUMNS[name]) <= set(t.columns) and len(t), name
        assert "light family" in out[name]["md"].read_text()


def test_vs_backbone_per_object_source(tmp_path):
    """vs_backbone per source of the test object (the plan's ObjectRecord.source, a mapping, not the object's name):
    rows per source in name order, F-RNG's paired difference and its interval within each source; objects the
    mapping lacks are 'other'; write_tables writes it when given the sources."""
    from frng.report import paper_tables as P

    rows = _per_image("backbone", "backbone", 0.0) + _per_image("full", "full", 1.0)
    rows = [dict(r, psnr=r["psnr"] + (0.5 if r["object"] == "o2" and r["run"] == "full" else 0.0)) for r in rows]
    sources = {"o0": "procedural", "o1": "procedural", "o2": "libero"}
    vs = P.vs_backbone_by_source(pd.DataFrame(rows), sources)
    cols = list(T.TABLE_COLUMNS["vs_backbone_by_source"])
    assert list(vs.columns[: len(cols)]) == cols
    assert list(vs["object_source"]) == ["libero", "libero", "procedural", "procedural"]
    libero, procedural = vs.iloc[0], vs.iloc[2]
    assert np.isclose(libero["dpsnr"], 1.5) and libero["objects"] == 1 and libero["n"] == 2
    assert np.isclose(procedural["dpsnr"], 1.0) and procedural["objects"] == 2 and procedural["better"] == 2
    other = P.vs_backbone_by_source(pd.DataFrame(rows), {"o0": "procedural"})
    assert list(other["object_source"]) == ["other", "other", "procedural", "procedural"]
    assert np.isclose(other.iloc[0]["dpsnr"], 1.25)  # o1 (+1.0) and o2 (+1.5) together


def test_ladder_per_material_class(tmp_path):
    """The ladder per material class: each class's objects only (the prior rows follow their object's class), the
    geometry columns kept, the paired differences within the class; write_tables writes it beside the others."""
    from frng.report.ladder import ladder_by_class

    rows = []
    for run, variant, shift in (("backbone", "backbone", 0.0), ("full", "full", 1.0)):
        rows += _per_image(run, variant, shift, objects=("o0", "o1"), dataset="diffuse")
        rows += _per_image(run, variant, 2 * shift, objects=("o2",), dataset="specular")
    df = pd.DataFrame(rows)
    prior = pd.DataFrame(
        [
            dict(
                r,
                task="relight",
                method="backbone-geometry+oracle-colour",
                depth_error=0.1 * (1 + (r["object"] == "o2")),
            )
            for r in _per_image("x", "x", 3.0)
        ]
    )
    lad = ladder_by_class(df, prior)
    assert list(lad.columns[: len(T.TABLE_COLUMNS["ladder_by_class"])]) == list(T.TABLE_COLUMNS["ladder_by_class"])
    assert list(zip(lad["dataset"], lad["step"])) == [(c, s) for c in ("diffuse", "specular") for s in "bde"]
    b = lad[lad["step"] == "b"].set_index("dataset")
    assert np.isclose(b.loc["diffuse", "depth_error"], 0.1) and np.isclose(b.loc["specular", "depth_error"], 0.2)
    assert b.loc["diffuse", "n"] == 4 and b.loc["specular", "n"] == 2  # o0, o1 x 2 lights; o2 x 2 lights
    e = lad[lad["step"] == "e"].set_index("dataset")
    assert np.isclose(e.loc["diffuse", "dpsnr"], 1.0) and np.isclose(e.loc["specular", "dpsnr"], 2.0)
    assert e.loc["diffuse", "objects"] == 2 and e.loc["specular", "objects"] == 1


def test_ladder_step_0_is_the_targets_noise_floor(tmp_path):
    """`frng noise-floor`'s CSV (frng.data.noise_floor.ladder_rows of its scored renders) becomes the ladder's first
    rows in the ladder and its per-class and per-family parts: step 0r, the reference's two renders against each
    other, and step 0, the tier's targets against the reference, with their metrics; the raw reference rows (no
    scores) stay out."""
    from frng.data import noise_floor as N
    from frng.report import ladder
    from frng.report import paper_tables as P

    assert N.LADDER_METHODS == {N.TIER: ladder.TARGETS_METHOD, N.HALF: ladder.REFERENCE_HALF_METHOD}
    scored = []
    for o, psnr in (("o0", 36.0), ("o2", 34.0)):
        for setting, value in ((N.REFERENCE, None), (N.HALF, 45.0), (N.TIER, psnr)):
            row = dict(object=o, material="diffuse", light="l0", view="v0", setting=setting, spp=32, seconds=0.4)
            if value is not None:
                row |= dict(
                    psnr=value, ssim=0.95, lpips=0.005, protocol="aligned", scale_r=1.0, scale_g=1.0, scale_b=1.0
                )
            scored.append(row)
    ladder_rows = N.ladder_rows(scored)
    assert [(r["method"], r["task"]) for r in ladder_rows] == [
        ("high-spp-reference-half", "relight"),
        (ladder.TARGETS_METHOD, "relight"),
    ] * 2
    noise_csv = tmp_path / "noise_floor.csv"
    pd.DataFrame(ladder_rows).to_csv(noise_csv, index=False)

    rows = _per_image("backbone", "backbone", 0.0) + _per_image("full", "full", 1.0)
    per_image = tmp_path / "per_image.csv"
    pd.DataFrame(rows).to_csv(per_image, index=False)
    prior_csv = tmp_path / "backbone.csv"
    pd.DataFrame([dict(r, task="relight", method="gt-depth+oracle-colour") for r in _per_image("x", "x", 3.0)]).to_csv(
        prior_csv, index=False
    )
    timing = _timing_file(tmp_path / "t.json")
    common = ("custom", [1, 1, 1], per_image, [timing], tmp_path / "tables", prior_csv)
    out = P.write_tables(*common, families={"l0": "sky", "l1": "studio"}, noise_csv=noise_csv)
    ladder = pd.read_csv(out["ladder"]["csv"], dtype={"step": str})
    assert list(ladder["step"]) == ["0r", "0", "a", "d", "e"]
    half, zero = ladder.iloc[0], ladder.iloc[1]
    assert zero["n"] == 2 and np.isclose(zero["psnr"], 35.0) and np.isclose(zero["lpips"], 0.005)
    assert np.isclose(half["psnr"], 45.0) and "reference" in half["what"]
    assert "noise floor" in zero["what"] and "row 0" in out["ladder"]["md"].read_text()
    by_class = pd.read_csv(out["ladder_by_class"]["csv"], dtype={"step": str})
    assert list(by_class["step"][:3]) == ["0r", "0", "a"] and np.isclose(by_class.iloc[1]["psnr"], 35.0)
    by_light = pd.read_csv(out["ladder_by_light"]["csv"], dtype={"step": str})
    studio = set(by_light[by_light["light_family"] == "studio"]["step"])
    assert list(by_light[by_light["light_family"] == "sky"]["step"][:3]) == ["0r", "0", "a"] and "0" not in studio
    # without the CSV (a config with render.noise_floor.views 0) the ladder starts at step a
    plain = P.write_tables(*common[:4], tmp_path / "plain", prior_csv)
    assert pd.read_csv(plain["ladder"]["csv"], dtype={"step": str})["step"].iloc[0] == "a"


def test_claims_judge_the_psnr_claims_under_both_protocols():
    """The claims table: every claim under the rows' protocol (aligned), the PSNR claims again from the per-image
    ``psnr_plain`` column: here w/o fine is below the full model aligned and above it plain (a colour error that
    alignment absorbs), and the two verdicts say so."""
    from frng.report.claims import CLAIMS
    from frng.report.paper_tables import claims

    rows = (
        _per_image("backbone", "backbone", 0.0)
        + _per_image("full", "full", 1.0)
        + _per_image("no-fine", "no-fine", 0.5)
    )
    for r in rows:
        r["psnr_aligned"] = r["psnr"]
        r["psnr_plain"] = r["psnr"] - 3.0 + (1.0 if r["run"] == "no-fine" else 0.0)  # plain: no-fine +0.5 over full
    timing = {"reconstruction_s": 1.0, "relight_ms_per_image": 20.0}
    timings = [{"F-RNG": timing, "backbone": timing, "resolution": 96, "spp": 32}]
    t = claims(pd.DataFrame(rows), timings)
    fine = t[t["claim"].str.startswith("w/o fine")].set_index("protocol")
    assert np.isclose(fine.loc["aligned", "measured"], -0.5) and fine.loc["aligned", "verdict"] == "held"
    assert np.isclose(fine.loc["plain", "measured"], 0.5) and fine.loc["plain", "verdict"] == "not held"
    plain = t[t["protocol"] == "plain"]
    assert len(plain) and set(plain["claim"]) == {c.text for c in CLAIMS if c.metric == "psnr"}
    # per-image rows from before both protocols were scored: the tier's protocol only
    old = pd.DataFrame(rows).drop(columns=["psnr_aligned", "psnr_plain"])
    assert set(claims(old, timings)["protocol"]) == {"aligned"}


def test_additions_table_is_f_rng_plus_over_the_paper_form_and_over_each_leave_out():
    """The additions table: F-RNG+ minus the paper form (every addition at once), then F-RNG+ minus F-RNG+ without
    each addition the rows have (paired, averaged over training seeds); empty without F-RNG+."""
    from frng.plan.variants import ADDITIONS, leave_out_variant
    from frng.report.paper_tables import ALL_ADDITIONS, additions_table

    rows = _per_image("full", "full", 0.0) + _per_image("plus", "plus", 1.5) + _per_image("plus@s1", "plus@s1", 1.7)
    loo = leave_out_variant("pixel_head")
    rows += _per_image(loo, loo, 0.5) + _per_image(loo + "@s1", loo + "@s1", 0.5)
    t = additions_table(pd.DataFrame(rows)).set_index("addition")
    assert list(t.index) == [ALL_ADDITIONS, "pixel_head"]
    assert np.isclose(t.loc[ALL_ADDITIONS, "dpsnr"], 1.6) and np.isclose(t.loc["pixel_head", "dpsnr"], 1.1)
    assert t.loc["pixel_head", "departs_from"] == ADDITIONS["pixel_head"].departs_from
    assert np.isclose(t.loc["pixel_head", "psnr"], 17.0 + 0.5 + 0.5 + 0.125)  # the reference's mean (no-pixel-head)
    assert np.isclose(t.loc["pixel_head", "dpsnr_lo"], 1.0) and np.isclose(t.loc["pixel_head", "dpsnr_hi"], 1.2)
    assert not len(additions_table(pd.DataFrame(_per_image("full", "full", 0.0))))
