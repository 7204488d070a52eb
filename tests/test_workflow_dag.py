"""Paper-scale DAG: `snakemake -n` on config/paper.yaml plans quickly and has the job counts the config implies.

Granularity (README "Running on a cluster"): one job per object for Blender curation and every per-object model
stage, one job per model variant for training, a handful of single jobs (env maps, previews, tables, figures).
At 1000 objects that is a few thousand jobs, which Snakemake plans in seconds; per-(object, light) jobs would be
~100k and take minutes just to plan (../shared/notes/slurm.md).

To cover a new rule, add a row to EXPECTED: rule name -> function of the filled-in config giving its job count.
Rows for rules the workflow does not have yet are harmless; a rule the workflow has but EXPECTED lacks fails the
test (so every rule's count is pinned down).
"""

from __future__ import annotations

import re
import subprocess

import pytest
from conftest import ROOT, venv_bin

from frng.plan import config as frng_config
from frng.plan import digests as frng_digests

SNAKEMAKE = venv_bin("snakemake")
PAPER = ROOT / "config" / "paper.yaml"
# CPU seconds: the paper DAG planned in 16.2 s user time without the baselines (1240 jobs) and 18.6 s with them (1767
# jobs: + curate_baselines, baseline_image, baseline_frng_nvs per test object, baseline_fit per (method, object)), on
# a loaded 2-core machine; the limit guards against planning that grows faster than the job count
PLAN_LIMIT_S = 26


from frng.plan.batches import DEFAULT_BATCH_OBJECTS, batches, rule_family  # noqa: E402
from frng.plan.variants import all_variants, extra_seeds, trained_variants  # noqa: E402


def n_objects(c: dict) -> int:
    o = c["objects"]
    return o["count"] + len(o.get("extra", [])) + o.get("libero", {}).get("count", 0)


def baseline_objects(c: dict) -> list[str]:
    from frng.baselines import plan as P
    from frng.plan import catalog

    return P.baseline_objects(c, P.test_objects(catalog.plan(c)))


def baseline_view_objects(c: dict) -> list[str]:
    """The objects rule curate_baselines renders: every test object with the image-based baseline, else the
    per-scene ones (none without dense views)."""
    from frng.plan import catalog

    objs = baseline_objects(c)
    return catalog.plan(c).split("test") if objs and c["baselines"]["image_based"] else objs


def n_test_objects(c: dict) -> int:
    o = c["objects"]
    return (
        o["test_count"]
        + sum(e["split"] == "test" for e in o.get("extra", []))
        + o.get("libero", {}).get("test_count", 0)
    )


def n_prior_batches(c: dict) -> int:
    """Jobs of a batched prior rule (rules/priors.smk, frng/plan/batches.py): each split cut into batches."""
    n_test = n_test_objects(c)
    return sum(len(batches(range(n), DEFAULT_BATCH_OBJECTS)) for n in (n_objects(c) - n_test, n_test))


# rule (a batched rule's family: backbone_cache for backbone_cache_train0, ...) -> expected number of jobs.
EXPECTED = {
    "all": lambda c: 1,
    "envmaps": lambda c: 1,  # one job bakes/rotates every map (seconds)
    "curate": n_objects,  # one Blender process per object renders all its views x lights
    "dataset_preview": lambda c: 1,  # one contact-sheet job over all objects
    "backbone_train": lambda c: 1,  # trained once on the training split, then frozen
    "idm_train": lambda c: int(c["idm"]["kind"] == "learned"),  # only the learned IDM is trained
    "backbone_cache": n_prior_batches,  # tokens of a batch of objects per job, one file per object
    "idm_priors": n_prior_batches,  # IDM passes of a batch of objects per job, one file per object
    "eval_backbone": lambda c: 1,
    "training_set_caches": lambda c: 1,  # one index of the training split's caches (the train jobs' fan-in)
    "training_set_priors": lambda c: int(any(v != "no-idm" for v in trained_variants(c))),
    "train": lambda c: len(trained_variants(c)),  # one job per variant; k2 (= full's K) is not retrained
    "model_alias": lambda c: len(all_variants(c)) - len(trained_variants(c)),  # k2: a copy of full
    "relight": n_test_objects,  # one job per test object: every F-RNG run + the backbone, timed side by side
    # one job per (test object, other training seed): that seed's {variant}@s{seed} runs (rules/relight.smk)
    "relight_seed": lambda c: n_test_objects(c) * len(extra_seeds(c)),
    "evaluate": lambda c: 1,
    "tables": lambda c: 1,
    "figures": lambda c: 1,
    # the baselines (rules/baselines.smk): one Blender job per test object (its target views under the input light,
    # + dense views for the per-scene objects), one fit job per (per-scene method, object) running every view count,
    # the image-based baseline and F-RNG's novel views per object, one scoring and one tables job
    "curate_baselines": lambda c: len(baseline_view_objects(c)),
    "baseline_fit": lambda c: len(c["baselines"]["methods"]) * len(baseline_objects(c)),
    "baseline_image": lambda c: len(baseline_view_objects(c)) if c["baselines"]["image_based"] else 0,
    "baseline_frng_nvs": lambda c: len(baseline_objects(c)),
    "baseline_eval": lambda c: int(bool(baseline_objects(c))),
    "baseline_tables": lambda c: int(bool(baseline_objects(c))),
    # the targets' noise floor (the ladder's step 0): one job, unless render.noise_floor.views is 0
    "noise_floor": lambda c: int(c["render"]["noise_floor"]["views"] > 0),
    # one digest file per rule with a config digest ({results}/.digests, rules/digests.smk), asked for by rule all
    "config_digest": lambda c: len(frng_digests.RULE_CONFIG_KEYS),
    # one record file per object (its plan entry and maps' records, {results}/.digests/objects), asked for by rule all
    "curate_record": n_objects,
}


def _job_counts(out: str) -> dict[str, int]:
    """Jobs per rule family (batched rules such as backbone_cache_train0 counted under theirs) from the job-count
    table of ``snakemake -n --quiet rules``."""
    counts = {}
    table = out.split("job count", 1)[-1] if "job count" in out else out
    for line in table.splitlines():
        m = re.match(r"^(\w+)\s+(\d+)\s*$", line)
        if m and m.group(1) != "total":
            counts[m.group(1)] = int(m.group(2))
    assert counts, f"no job-count table in:\n{out[-3000:]}"
    families = {}
    for rule, n in counts.items():
        families[rule_family(rule)] = families.get(rule_family(rule), 0) + n
    return families


@pytest.fixture(scope="module")
def paper_plan(paper_dry_run):
    """(config, jobs per rule family, planning CPU seconds) of the session's paper dry run (conftest.py)."""
    assert paper_dry_run.proc.returncode == 0, paper_dry_run.output[-3000:]
    counts = _job_counts(paper_dry_run.output)
    print(f"\npaper DAG planned in {paper_dry_run.cpu_s:.1f} s CPU; jobs per rule: {counts}")
    return frng_config.load(PAPER), counts, paper_dry_run.cpu_s


def test_paper_dag_plans_fast(paper_plan):
    config, counts, elapsed = paper_plan
    assert elapsed < PLAN_LIMIT_S, f"paper DAG took {elapsed:.1f} s (CPU) to plan ({sum(counts.values())} jobs)"


def test_paper_dag_job_counts_match_config(paper_plan):
    config, counts, _ = paper_plan
    unknown = sorted(set(counts) - set(EXPECTED))
    assert not unknown, f"rules without an expected job count (add them to EXPECTED): {unknown}"
    wrong = {rule: (counts[rule], EXPECTED[rule](config)) for rule in counts if counts[rule] != EXPECTED[rule](config)}
    assert not wrong, f"rule: (planned, expected from config): {wrong}"
    # paper scale stays at per-object granularity: thousands of jobs, not 100k
    assert sum(counts.values()) < 20_000


def test_slurm_profile_resolves(tmp_path):
    """profiles/slurm parses, takes the partition from FRNG_SLURM_PARTITION and gives rules their set-resources
    (planned on the toy workflow with the real rule names `curate`/`tables`; no cluster needed for -n)."""
    import os

    env = {**os.environ, "FRNG_SLURM_PARTITION": "mypart", "FRNG_SLURM_ACCOUNT": "myacct"}
    r = subprocess.run(
        [
            SNAKEMAKE,
            "--snakefile",
            str(ROOT / "tests" / "slurm_toy" / "Snakefile"),
            "--directory",
            str(tmp_path),
            "--profile",
            str(ROOT / "profiles" / "slurm"),
            "-n",
        ],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=120,
        env=env,
    )
    out = r.stdout + r.stderr
    assert r.returncode == 0, out[-3000:]
    jobs = {m.group(1): m.group(2) for m in re.finditer(r"(?ms)^rule (\w+):.*?^\s+resources: ([^\n]+)", out)}
    assert "slurm_partition=mypart" in jobs["curate"] and "slurm_account=myacct" in jobs["curate"]
    assert "cpus_per_task=8" in jobs["curate"] and "mem_mb=16000" in jobs["curate"]
    assert "cpus_per_task=1" in jobs["tables"]
