"""Planning: the paper-scale DAG plans quickly; the smoke DAG lists the expected dataset jobs; the dataset
plan keeps test lights out of training."""

import re
import subprocess

import pytest
from conftest import ROOT, venv_bin

from frng.plan import catalog, dataset_config
from frng.plan import config as frng_config
from frng.plan import variants as V


def dry_run(configfile, results, *extra):
    """``configfile``: one path, or a list merged in order (an overlay after its base)."""
    cmd = [
        venv_bin("snakemake"),
        "--snakefile",
        "workflow/Snakefile",
        "--configfile",
        *([configfile] if isinstance(configfile, str) else configfile),
        "--config",
        f"results={results}",
        "-n",
        "--quiet",
        "rules",
        *extra,
    ]
    return subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=120)


def job_counts(text):
    return {m.group(1): int(m.group(2)) for m in re.finditer(r"^(\w+)\s+(\d+)$", text, re.M)}


def test_paper_dry_run_plans_in_seconds(paper_dry_run):
    """CPU seconds of the planning process (wall time on the shared 2-core machine is noisy; it is printed). The
    baselines' jobs (rules/baselines.smk, 527 of the paper DAG's 1767) took it from 16.2 to 18.6 s user time on the
    project's machine (20.2 s CPU within the test suite), hence 24 s. The session's one paper dry run (conftest.py)."""
    proc, cpu = paper_dry_run.proc, paper_dry_run.cpu_s
    assert proc.returncode == 0, proc.stderr[-3000:]
    counts = job_counts(paper_dry_run.output)
    libero = frng_config.load(ROOT / "config/paper.yaml")["objects"]["libero"]["count"]
    assert counts["curate"] == 1000 + libero and counts["envmaps"] == 1  # generated objects + the real ones
    assert cpu < 24.0, f"paper dry-run took {cpu:.1f} s CPU ({paper_dry_run.wall_s:.1f} s wall)"


def test_smoke_dry_run_lists_dataset_jobs(tmp_path):
    proc = dry_run("config/smoke.yaml", tmp_path / "results")
    assert proc.returncode == 0, proc.stderr[-3000:]
    counts = job_counts(proc.stdout + proc.stderr)
    assert counts["envmaps"] == 1 and counts["curate"] == 4 and counts["dataset_preview"] == 1


@pytest.mark.parametrize("configfile", ["config/smoke.yaml", "config/config.yaml"])
def test_snakemake_lint_is_clean(configfile, tmp_path):
    """`snakemake --lint` (as `make lint`) reports nothing: e.g. no folder params hard-coded beside the outputs
    they are a prefix of (they are derived from the output, so they follow it on a non-shared filesystem)."""
    cmd = [
        venv_bin("snakemake"),
        "--snakefile",
        "workflow/Snakefile",
        "--configfile",
        configfile,
        "--config",
        f"results={tmp_path / 'results'}",
        "--lint",
    ]
    proc = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, (proc.stdout + proc.stderr)[-3000:]


@pytest.mark.parametrize("path", ["config/smoke.yaml", "config/config.yaml", "config/paper.yaml"])
def test_plan_splits_lights_and_materials(path):
    cfg = frng_config.load(ROOT / path)
    cat = catalog.plan(cfg)
    env = {e.name: e for e in cat.envmaps}
    bases = {s: {e.base for e in cat.envmaps if e.split == s} for s in ("train", "test")}
    assert bases["train"] and bases["test"] and not bases["train"] & bases["test"]
    for o in cat.objects:
        assert all(env[l].split == o.split for l in o.input_lights + o.target_lights), o.id
        assert len(set(o.target_lights)) == cfg["render"]["target_lights"]
    libero = cfg["objects"]["libero"]
    assert len(cat.split("test")) == cfg["objects"]["test_count"] + libero["test_count"]
    assert sum(o.source == "libero" and o.split == "test" for o in cat.objects) == libero["test_count"]
    assert catalog.plan(frng_config.load(ROOT / path)) == cat  # deterministic
    n = cfg["objects"]["count"]
    mats = [o.material for o in cat.objects if o.source != "libero"]  # the mix is the generated objects'
    for cls, frac in cfg["objects"]["material_mix"].items():
        assert abs(mats.count(cls) - frac * n) <= max(1, 0.01 * n)


def test_too_few_test_lights_is_a_plan_error():
    cfg = frng_config.load(ROOT / "config/smoke.yaml", {"render": {"target_lights": 5}})
    with pytest.raises(dataset_config.CatalogError, match="target_lights=5"):
        catalog.plan(cfg)


def test_seeds_overlay_adds_the_second_seed_to_the_default_dag(tmp_path):
    """config/seeds.yaml (`make seeds`) merged over config/config.yaml: a valid config that differs from the default
    tier only in train.seeds, and plans its jobs plus seed 1 of the full model and each ablation."""
    base = frng_config.load(ROOT / "config/config.yaml")
    seeds = frng_config.load_overlaid(ROOT / "config/config.yaml", ROOT / "config/seeds.yaml")
    flat_base = frng_config.flatten(base)
    changed = {k for k, v in frng_config.flatten(seeds).items() if flat_base.get(k) != v}
    assert changed == {"train.seeds"} and seeds["results"] == base["results"]
    plain = dry_run("config/config.yaml", tmp_path / "a")
    overlay = dry_run(["config/config.yaml", "config/seeds.yaml"], tmp_path / "b")
    assert plain.returncode == 0 and overlay.returncode == 0, (plain.stderr + overlay.stderr)[-3000:]
    a, b = job_counts(plain.stdout + plain.stderr), job_counts(overlay.stdout + overlay.stderr)
    added = {k: b[k] - a.get(k, 0) for k in b if b[k] != a.get(k, 0)}
    n_models = len(V.seeded_bases(seeds))  # full and each ablation once more
    assert added == {"train": n_models, "relight_seed": a["relight"], "total": n_models + a["relight"]}, (a, b)
