"""The README is a short guide (issue 58): at most ~200 lines, none over 200 characters, no commit hash, and a newcomer
reaches how to run it, what it writes, their own photos, the results and the cluster in the first 120 lines; the
reference lives in docs/ (one page per topic), history in CHANGELOG.md and docs/studies/."""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"

# heading -> what a newcomer looks for under it; each within the first EARLY lines
EARLY = 120
MUST_BE_EARLY = {
    "## Quickstart": "how to run it (`make reproduce`, `make test`)",
    "## What you get": "the results tree and `snakemake --report`",
    "## Your own photos": "`frng reconstruct`",
    "## Results": "the generated results block",
    "## Running on a cluster": "the SLURM profile",
}
# sections other issues fill (their headings stay)
MUST_EXIST = ("## Reliability", "## Look at an asset", "## Status", "## Layout", "## Citation")
# links another issue's page answers; it may not be written yet when this test runs
WRITTEN_ELSEWHERE = {"docs/reliability.md"}
TOPICS = (
    "architecture",
    "dataset-and-curation",
    "priors",
    "model-and-training",
    "relighting-and-metrics",
    "provenance-and-reproducibility",
    "capture-and-assets",
    "benchmarks",
    "cluster",
    "performance",
)


def lines() -> list[str]:
    return README.read_text().splitlines()


def test_short_lines_and_no_commit_hash():
    text = lines()
    assert len(text) <= 200, f"README.md has {len(text)} lines (a guide of at most ~200; reference goes to docs/)"
    long = [(i + 1, len(line)) for i, line in enumerate(text) if len(line) > 200]
    assert not long, f"README.md lines over 200 characters (line, length): {long}"
    hashes = [
        (i + 1, h)
        for i, line in enumerate(text)
        for h in re.findall(r"(?<![0-9A-Za-z_/.-])[0-9a-f]{7,40}(?![0-9A-Za-z_])", line)
        if re.search(r"[a-f]", h) and re.search(r"[0-9]", h)
    ]
    assert not hashes, f"README.md names commits (line, hash): {hashes}; history goes to CHANGELOG.md"


def test_a_newcomer_reaches_the_essentials_early():
    text = lines()
    headings = {line.strip(): i + 1 for i, line in enumerate(text) if line.startswith("#")}
    for heading, what in MUST_BE_EARLY.items():
        assert heading in headings, f"README.md lacks {heading!r} ({what})"
        assert headings[heading] <= EARLY, f"README.md {heading!r} ({what}) is at line {headings[heading]} > {EARLY}"
    for heading in MUST_EXIST:
        assert heading in headings, f"README.md lacks {heading!r}"
    quick = "\n".join(text[headings["## Quickstart"] : headings["## What you get"]])
    assert "make reproduce" in quick and "make test" in quick and "minutes" in quick and "GB" in quick
    assert "--report" in "\n".join(text[headings["## What you get"] : headings["## Your own photos"]])
    assert "frng reconstruct" in "\n".join(text[headings["## Your own photos"] : headings["## Results"]])


def test_one_picture_and_every_link_resolves():
    text = README.read_text()
    images = re.findall(r"!\[[^\]]*\]\(([^)]+)\)", text)
    assert images and all((ROOT / p).is_file() for p in images), images
    links = [t for t in re.findall(r"\]\(([^)#]+)\)", text) if not t.startswith(("http://", "https://"))]
    missing = [t for t in links if not (ROOT / t).exists() and t not in WRITTEN_ELSEWHERE]
    assert not missing, f"README.md links to missing files: {missing}"


def test_reference_by_topic_and_history_out_of_the_guide():
    docs = ROOT / "docs"
    for topic in TOPICS:
        page = docs / f"{topic}.md"
        assert page.is_file(), f"docs/{topic}.md missing"
        assert f"({topic}.md)" in (docs / "README.md").read_text(), f"docs/README.md does not list {topic}.md"
    changelog = (ROOT / "CHANGELOG.md").read_text()
    rows = [line for line in changelog.splitlines() if re.match(r"\| 20\d\d-\d\d-\d\d \|", line)]
    assert rows, "CHANGELOG.md has no reproduction rows"
    for row in rows:  # date | commit | tier | minutes | headline | details
        assert len(row.strip("|").split(" | ")) == 6, row
    linked = set(re.findall(r"\((docs/studies/[^)]+\.md)\)", changelog))
    for study in linked:
        assert (ROOT / study).is_file(), study
    unlinked = [p.name for p in (docs / "studies").glob("20*.md") if f"docs/studies/{p.name}" not in linked]
    assert not unlinked, f"studies CHANGELOG.md does not link: {unlinked}"
    assert not (docs / "results-history.md").exists(), "docs/results-history.md moved to docs/studies/"
    # docs/figures holds only what a page shows
    shown = set()
    for page in [README, *docs.rglob("*.md")]:
        for link in re.findall(r"\]\(([^)]+\.(?:png|gif))\)", page.read_text()):
            shown.add((page.parent / link).resolve())
    unshown = [p.relative_to(ROOT) for p in (docs / "figures").rglob("*.png") if p.resolve() not in shown]
    assert not unshown, f"figures no page shows (remove them): {unshown}"


def test_changelog_rows_are_short_and_linked():
    """Issue 89: one CHANGELOG row per reproduction, each cell at most ~200 characters (240 allowed), each row with a
    link to its study page or docs/results.md; a run's longer text lives on the linked page."""
    changelog = (ROOT / "CHANGELOG.md").read_text()
    rows = [line for line in changelog.splitlines() if re.match(r"\| 20\d\d-\d\d-\d\d \|", line)]
    assert rows, "CHANGELOG.md has no reproduction rows"
    long = [(row[:40], len(cell)) for row in rows for cell in row.strip().strip("|").split(" | ") if len(cell) > 240]
    assert not long, f"CHANGELOG.md cells over 240 characters (row, length): {long}"
    unlinked = [row[:40] for row in rows if not re.search(r"\]\(docs/[^)]+\.md(#[^)]*)?\)", row)]
    assert not unlinked, f"CHANGELOG.md rows without a link to docs/: {unlinked}"
    for page, anchor in re.findall(r"\]\((docs/[^)#]+\.md)#([^)]+)\)", changelog):
        assert f'<a id="{anchor}"></a>' in (ROOT / page).read_text(), (page, anchor)
