"""The generated results pages (frng/report/results_page.py, ``frng results-page``, ``frng tables --results-page``).

The results tree is written here: per-image scores for every run the smoke config implies (``frng.plan.variants.runs``),
the priors' and the light-sensitivity CSVs and timing files, turned into tables by the pipeline's own
``frng.report.paper_tables.write_tables``, so the tables have the smoke tier's structure without a pipeline run.
The committed ``docs/results.md`` and README block must have the structure (headings, table columns) a regeneration
from such a tree has: a change of the tables or of the page format fails here until the pages are regenerated.
"""

from __future__ import annotations

import os
import re
import shutil
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import yaml
from data_helpers import protocol_scores

from frng import io
from frng.plan import config as frng_config
from frng.plan import variants as V
from frng.report import results_page as RP
from frng.report.ladder import LADDER_STEPS
from frng.report.paper_tables import write_tables

ROOT = Path(__file__).resolve().parents[1]
OBJECTS = (("o_diffuse", "diffuse"), ("o_specular", "specular"), ("o_fur", "fur"))
LIGHTS = ("l0", "l1")
T0 = 1_700_000_000.0


def _scores(psnr: float) -> dict:
    return protocol_scores(psnr, 0.4 + psnr / 100, 0.3 - psnr / 100, (1.1, 0.9, 1.0), (1.2, 1.0, 0.8), psnr + 3.0)


def write_results(folder: Path) -> Path:
    """A smoke-structured results folder: config.yaml, logs/, metrics -> tables/, figures/ablation.png."""
    config = frng_config.load(ROOT / "config" / "smoke.yaml")
    runs = V.runs(config)
    rows = []
    for i, (obj, dataset) in enumerate(OBJECTS):
        for r_i, run in enumerate(runs):
            for l_i, light in enumerate(LIGHTS):
                for view in ("tgt_000", "tgt_001"):
                    base = 15.0 + i + 0.3 * l_i + (0.0 if run.method == V.BACKBONE else 1.0 + 0.05 * r_i)
                    rows.append(
                        dict(
                            dataset=dataset,
                            object=obj,
                            run=run.name,
                            method=run.method,
                            variant=run.variant,
                            views=run.views,
                            k=run.k_percent,
                            seed="" if run.seed is None else run.seed,
                            decoder="base" if run.decoder == "base" else "",
                            light=light,
                            view=view,
                            protocol="aligned",
                            **_scores(base + (0.1 if view == "tgt_001" else 0.0)),
                        )
                    )
    metrics = folder / "metrics"
    metrics.mkdir(parents=True)
    pd.DataFrame(rows).to_csv(metrics / "relight_per_image.csv", index=False)
    prior = [
        dict(task=task, method=method, object=obj, light=light, view="tgt_000", **_scores(20.0 - k))
        for k, (_, _, source, task, method, _) in enumerate(LADDER_STEPS)
        if source == "prior"
        for obj, _ in OBJECTS
        for light in LIGHTS
    ]
    pd.DataFrame(prior).to_csv(metrics / "backbone.csv", index=False)
    cross = [
        dict(run=run, light=light, scored_against=other, object=obj, view="tgt_000", dataset=ds, **_scores(psnr))
        for run, psnr in (("backbone", 14.0), ("full", 14.5), ("ground-truth", 13.0))
        for obj, ds in OBJECTS
        for light, other in zip(LIGHTS, LIGHTS[::-1], strict=True)
    ]
    pd.DataFrame(cross).to_csv(metrics / "relight_cross_light.csv", index=False)
    timing = []
    for obj, _ in OBJECTS:
        timing.append(folder / "relight" / "timing" / f"{obj}.json")
        io.write_json(
            timing[-1],
            {
                "device": "cpu",
                "resolution": 32,
                "spp": 8,
                "F-RNG": {"reconstruction_s": 1.0, "relight_ms_per_image": 20.0},
                "backbone": {"reconstruction_s": 0.2, "relight_ms_per_image": 40.0},
            },
        )
    (folder / "config.yaml").write_text(yaml.safe_dump({**config, "results": str(folder)}))
    (folder / "logs").mkdir()
    (folder / "logs" / "envmaps.log").write_text("first job\n")
    os.utime(folder / "logs" / "envmaps.log", (T0, T0))
    write_tables(
        "smoke",
        [1, 1, 1],
        metrics / "relight_per_image.csv",
        timing,
        folder / "tables",
        metrics / "backbone.csv",
        metrics / "relight_cross_light.csv",
        families=dict(zip(LIGHTS, ("sky", "studio"), strict=True)),
        sources={obj: ("libero" if i else "procedural") for i, (obj, _) in enumerate(OBJECTS)},
    )
    write_baseline_tables(folder, metrics)
    for t in (folder / "tables").iterdir():
        os.utime(t, (T0 + 600, T0 + 600))  # the tables, 10 minutes after the first job
    for name in RP.FIGURES:  # every figure the page shows (the default tier makes them all)
        io.write_png(folder / "figures" / name, np.full((4, 6, 3), 0.5, np.float32))
    return folder


def write_baseline_tables(folder: Path, metrics: Path) -> None:
    """Tables 2-3, the views table and the findings (frng.report.baseline_tables) from per-image scores of F-RNG,
    per-scene 3dgs / gsir at two view counts and the image-based re-shading, as the default tier has them."""
    from frng.report import baseline_tables as BT

    runs = [  # (run, method, family, views, tasks)
        (BT.FRNG, "F-RNG", "frng", 6, ("relight",)),
        (BT.FRNG_NVS, "F-RNG", "frng", 6, ("nvs",)),
        *[(f"3dgs-v{n}", "3dgs", "dense", n, ("nvs",)) for n in (4, 8)],
        *[(f"gsir-v{n}", "gsir", "dense", n, ("relight", "nvs")) for n in (4, 8)],
        ("idm-reshade", "idm-reshade", "image", 1, ("relight",)),
    ]
    rows, timing = [], []
    for k, (run, method, family, views, tasks) in enumerate(runs):
        for i, (obj, dataset) in enumerate(OBJECTS):
            timing.append(dict(run=run, method=method, family=family, views=views, source="trained here", object=obj,
                               fit_seconds=10.0 + k, relight_seconds_per_image=0.05))  # fmt: skip
            for task in tasks:
                for light in LIGHTS if task == "relight" else ("l_in",):
                    for view in ("tgt_000", "tgt_001"):
                        rows.append(dict(task=task, run=run, method=method, family=family, views=views,
                                         source="trained here", object=obj, dataset=dataset, scene="", light=light,
                                         view=view, protocol="aligned", **_scores(16.0 + i + 0.2 * k)))  # fmt: skip
    pd.DataFrame(rows).to_csv(metrics / "baselines_per_image.csv", index=False)
    pd.DataFrame(timing).to_csv(metrics / "baselines_timing.csv", index=False)
    BT.write_tables(metrics / "baselines_per_image.csv", metrics / "baselines_timing.csv", folder / "tables", "smoke",
                    [1, 1, 1])  # fmt: skip


@pytest.fixture(scope="module")
def results(tmp_path_factory) -> Path:
    return write_results(tmp_path_factory.mktemp("page") / "results")


def readme_with_block(path: Path) -> Path:
    path.write_text(f"# Project\n\nbefore\n\n{RP.BEGIN}\nold\n{RP.END}\n\nafter\n")
    return path


def structure(text: str) -> list[str]:
    """Headings and table header rows, in order: what a regeneration must keep."""
    out = []
    lines = text.splitlines()
    for i, line in enumerate(lines):
        if line.startswith("#"):
            out.append(line)
        elif line.startswith("|") and i + 1 < len(lines) and re.fullmatch(r"\|(:?-+:?\|)+", lines[i + 1]):
            out.append(line)
    return out


def test_page_and_block_from_a_results_folder(results, tmp_path):
    docs, readme = tmp_path / "docs", readme_with_block(tmp_path / "README.md")
    out = RP.write_pages(results, docs / "results.md", readme, repo=tmp_path)
    page = out.page.read_text()
    assert "| commit | `unknown` |" in page  # tmp_path is no git checkout
    assert "| minutes (first job's log to the tables) | 10 |" in page
    assert "| tier | smoke |" in page and "| test objects | 3 |" in page
    assert "| date (UTC) | 2023-11-14 |" in page  # T0 + 600 s
    digest = re.search(r"\| config digest \| `([0-9a-f]{16})` \|", page)
    assert digest, page[:800]
    assert "relighting on cpu" in page
    for name, title in RP.TABLE_TITLES.items():
        if (results / "tables" / f"{name}.md").exists():
            assert f"## {title} (`tables/{name}`)" in page
    assert (docs / "figures" / "results" / "ablation.png").read_bytes() == (
        results / "figures" / "ablation.png"
    ).read_bytes()
    assert "![Every test object under every ablation" in page and "(figures/results/ablation.png)" in page
    text = readme.read_text()
    assert text.startswith("# Project\n\nbefore\n\n") and text.endswith("\n\nafter\n") and "\nold\n" not in text
    block = RP.readme_block(text)
    head = RP.headline(RP.read_tables(results / "tables"))
    assert [r[0] for r in head.rows] == [
        "F-RNG (ours)",
        "F-RNG+ (ours, with the additions)",
        "backbone (RelitLRM-style)",
    ]
    assert head.rows[0][-1] == "**20.0**" and head.rows[2][-1] == "40.0"  # ms/image from the timing footer
    assert head.rows[1][-1] == ""  # F-RNG+ untimed here
    assert RP.render_table(head.header, head.align, head.rows) in block and "(docs/results.md)" in block
    assert "(docs/figures/results/ablation.png)" in block
    assert out.changelog == (
        "| 2023-11-14 | `unknown` | smoke | 10 | 17.20 / 17.45 / 16.20; ΔPSNR +1.00 [1.00, 1.00] (interior +1.00 [1.00, 1.00]), "
        "ΔLPIPS -0.0100 [-0.0100, -0.0100] "
        "| [results](docs/results.md) |"
    )
    # the same folder again: the same bytes (a regeneration is deterministic)
    again = RP.write_pages(results, docs / "results.md", readme, repo=tmp_path)
    assert again.page.read_text() == page and readme.read_text() == text


def test_overrides_state_an_earlier_runs_provenance(results, tmp_path):
    out = RP.write_pages(results, tmp_path / "r.md", repo=tmp_path, overrides={"commit": "abc", "minutes": 72.4})
    page = out.page.read_text()
    stated = " (stated by hand: the results folder did not record it) |"
    assert "| commit | `abc`" + stated in page and "| minutes (first job's log to the tables) | 72.4" + stated in page
    with pytest.raises(RP.ResultsPageError, match="unknown provenance fields"):
        RP.write_pages(results, tmp_path / "r.md", overrides={"commmit": "abc"})


def test_the_commit_is_the_checkouts_and_dirty_only_beyond_the_generated_files(tmp_path):
    import subprocess

    def git(*args):
        return subprocess.run(
            ["git", "-c", "user.name=t", "-c", "user.email=t@t", "-C", str(tmp_path), *args],
            capture_output=True,
            text=True,
            check=True,
        ).stdout.strip()

    assert RP.git_commit(tmp_path) == "unknown"  # no checkout yet
    git("init", "-q")
    (tmp_path / "docs").mkdir()
    for name in ("README.md", "docs/results.md", "code.py"):
        (tmp_path / name).write_text("v1\n")
    git("add", "README.md", "docs/results.md", "code.py")
    git("commit", "-q", "-m", "one")
    head = git("rev-parse", "--short=12", "HEAD")
    assert RP.git_commit(tmp_path / "docs") == head
    (tmp_path / "README.md").write_text("regenerated\n")
    (tmp_path / "docs" / "results.md").write_text("regenerated\n")
    assert RP.git_commit(tmp_path) == head  # the pages it writes do not make the checkout dirty
    (tmp_path / "code.py").write_text("v2\n")
    assert RP.git_commit(tmp_path) == head + "+dirty"


def test_bad_input_is_one_line_naming_the_file(results, tmp_path):
    with pytest.raises(RP.ResultsPageError, match=re.escape(str(tmp_path / "none" / "tables"))):
        RP.write_pages(tmp_path / "none", tmp_path / "r.md")
    plain = tmp_path / "README.md"
    plain.write_text("# no markers\n")
    with pytest.raises(RP.ResultsPageError, match=f"{re.escape(str(plain))}: no results block"):
        RP.write_pages(results, tmp_path / "r.md", plain)
    assert not (tmp_path / "r.md").exists()  # nothing written
    broken = shutil.copytree(results, tmp_path / "broken")
    (broken / "tables" / "k.md").write_text("caption only\n")
    with pytest.raises(RP.ResultsPageError, match=f"{re.escape(str(broken / 'tables' / 'k.md'))}: no Markdown table"):
        RP.write_pages(broken, tmp_path / "r.md")
    (broken / "tables" / "k.md").unlink()
    (broken / "tables" / "vs_backbone.md").unlink()
    with pytest.raises(RP.ResultsPageError, match="vs_backbone.md: missing"):
        RP.write_pages(broken, tmp_path / "r.md")


def test_subcommand_writes_the_pages(results, tmp_path):
    from frng.cli import main

    readme = readme_with_block(tmp_path / "README.md")
    with pytest.raises(SystemExit) as e:
        main(
            [
                "results-page",
                "--results",
                str(results),
                "--results-page",
                str(tmp_path / "docs" / "results.md"),
                "--readme",
                str(readme),
                "--commit",
                "0123abc",
            ]
        )
    assert e.value.code in (0, None)
    assert "| commit | `0123abc` (stated by hand" in (tmp_path / "docs" / "results.md").read_text()
    assert "F-RNG (ours)" in RP.readme_block(readme.read_text())


def test_committed_pages_match_a_regeneration(results, tmp_path):
    """docs/results.md and README.md's results block have a regeneration's headings and table columns."""
    readme = tmp_path / "README.md"
    shutil.copyfile(ROOT / "README.md", readme)
    out = RP.write_pages(results, tmp_path / "docs" / "results.md", readme, repo=tmp_path)
    committed = (ROOT / "docs" / "results.md").read_text()
    assert structure(committed) == structure(out.page.read_text()), (
        "docs/results.md's headings or table columns differ from a regeneration: run `frng results-page` "
        "(or the rule tables of the default tier) and commit the pages"
    )
    block = RP.readme_block((ROOT / "README.md").read_text())
    assert structure(block) == structure(RP.readme_block(readme.read_text()))
    assert committed.count("## Provenance") == 1 and "<!-- generated by `frng results-page`" in committed
    # the committed page's figures are in the tree
    for link in re.findall(r"\]\((figures/[^)]+)\)", committed):
        assert (ROOT / "docs" / link).is_file(), link


def test_the_tables_stage_writes_the_pages_when_told_where(results, tmp_path):
    """What the rule tables runs for the default tier: `frng tables ... --results-page PAGE --readme README`."""
    from frng.cli import main

    folder = shutil.copytree(results, tmp_path / "results")
    config = folder / "config.yaml"
    config.write_text(yaml.safe_dump({**yaml.safe_load(config.read_text()), "results": str(folder)}))
    readme = readme_with_block(tmp_path / "README.md")
    metrics = folder / "metrics"
    argv = ["tables", "--config", str(config), "--metrics", str(metrics / "relight_per_image.csv")]
    argv += ["--timing", *map(str, sorted((folder / "relight" / "timing").glob("*.json")))]
    argv += [
        "--prior-metrics",
        str(metrics / "backbone.csv"),
        "--cross-light",
        str(metrics / "relight_cross_light.csv"),
    ]
    argv += [
        "--out",
        str(folder / "tables"),
        "--results-page",
        str(tmp_path / "docs" / "results.md"),
        "--readme",
        str(readme),
    ]
    with pytest.raises(SystemExit) as e:
        main(argv)
    assert e.value.code in (0, None)
    page = (tmp_path / "docs" / "results.md").read_text()
    assert "| tier | smoke |" in page and (tmp_path / "docs" / "figures" / "results" / "ablation.png").is_file()
    assert "F-RNG (ours)" in RP.readme_block(readme.read_text())
