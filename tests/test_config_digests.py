"""Config edits rerun exactly what they affect (issue 12, problem 3).

Every rule declares ``params: config_digest=`` a digest of the config keys its stage reads (``CONFIG_READS`` of
``frng/stages/<rule>.py``, gathered by ``frng/plan/digests.py``), so Snakemake's params trigger reruns the rules whose keys were edited and, through their
rebuilt outputs, the rules downstream; the other rules stay.

The workflow test needs a results folder where every job has run with a known config, without running any stage:
every output the smoke tier plans is created empty, then ``snakemake --touch --forceall`` "runs" every job as a touch,
which records each job's params in ``.snakemake`` metadata as a real run does. A dry run with that config has
nothing to do; a dry run with one key edited lists the jobs the edit reruns. Everything lives under a temporary
folder (results and ``--directory``), never the repository's ``results/``."""

import copy
import os
import re
import subprocess
from pathlib import Path

import pytest
import yaml
from conftest import ROOT, venv_bin

from frng.plan import config as frng_config
from frng.plan import digests as frng_digests
from frng.plan.batches import DEFAULT_BATCH_OBJECTS, batches, rule_family
from frng.plan.variants import seeded_bases, trained_variants

# -- the digest --------------------------------------------------------------------------------------------------


def test_digest_is_short_stable_and_ignores_key_order():
    cfg = frng_config.load(ROOT / "config" / "smoke.yaml")
    d = frng_digests.config_digest(cfg, ["train", "frng.hidden", "seed"])
    assert re.fullmatch(r"[0-9a-f]{16}", d)
    assert frng_digests.config_digest(copy.deepcopy(cfg), ["seed", "train", "frng.hidden"]) == d
    shuffled = {k: cfg[k] for k in reversed(list(cfg))}  # mapping order does not matter either
    assert frng_digests.config_digest(shuffled, ["frng.hidden", "seed", "train"]) == d
    cfg["train"]["steps"] += 1
    assert frng_digests.config_digest(cfg, ["train", "frng.hidden", "seed"]) != d


def test_digest_of_a_missing_key_is_null():
    keys = ["a.b"]
    assert frng_digests.config_digest({}, keys) == frng_digests.config_digest({"a": {}}, keys)
    assert frng_digests.config_digest({"a": {"b": None}}, keys) == frng_digests.config_digest({}, keys)
    assert frng_digests.config_digest({"a": {"b": 0}}, keys) != frng_digests.config_digest({}, keys)


def test_digest_exclusions():
    keys = ["shading", "!shading.spp_infer"]
    base = {"shading": {"spp_infer": 32, "spp_train": 16}, "seed": 0}
    d = frng_digests.config_digest(base, keys)
    assert frng_digests.config_digest({**base, "shading": {"spp_infer": 64, "spp_train": 16}}, keys) == d
    assert frng_digests.config_digest({**base, "shading": {"spp_infer": 32, "spp_train": 8}}, keys) != d
    assert frng_digests.config_digest({**base, "seed": 1}, keys) == d
    assert base["shading"]["spp_infer"] == 32  # the config is not modified
    with pytest.raises(ValueError, match="train.steps"):
        frng_digests.config_digest(base, ["shading", "!train.steps"])


def test_map_names_schema_keys_only():
    """A misspelt key would digest as null for ever; results and the overwrite switch are never digested."""
    assert frng_digests.unknown_digest_keys() == []
    assert frng_digests.unknown_digest_keys({"properties": {"results": {"type": "string"}}}) != []


def test_every_schema_key_is_read_by_some_rule():
    """A key added to the schema must be added to the digests of the rules whose stages read it."""
    assert frng_digests.undigested_keys() == []
    schema = frng_config.load_schema()
    schema["properties"]["new_key"] = {"type": "integer"}
    schema["properties"]["train"]["properties"]["new_leaf"] = {"type": "integer"}
    assert frng_digests.undigested_keys(schema) == ["new_key"]  # train.* is digested whole (rule train)
    cfg = frng_config.load(ROOT / "config" / "smoke.yaml")
    moved = {**copy.deepcopy(cfg), "results": "elsewhere"}
    for rule in frng_digests.RULE_CONFIG_KEYS:
        assert frng_digests.rule_digest(moved, rule) == frng_digests.rule_digest(cfg, rule), rule


def test_check_rule_digests_names_each_problem():
    cfg = frng_config.load(ROOT / "config" / "smoke.yaml")
    good = {rule: frng_digests.rule_digest(cfg, rule) for rule in frng_digests.RULE_CONFIG_KEYS} | {"all": None}
    frng_digests.check_rule_digests(cfg, good)
    with pytest.raises(frng_config.ConfigError, match=r"rule train: needs .*rule_digest\(config, \"train\"\)"):
        frng_digests.check_rule_digests(cfg, good | {"train": None})
    with pytest.raises(frng_config.ConfigError, match=r"rule new_stage: no CONFIG_READS in frng/stages/new_stage.py"):
        frng_digests.check_rule_digests(cfg, good | {"new_stage": "x"})
    with pytest.raises(
        frng_config.ConfigError, match=r"frng/stages/figures.py \(CONFIG_READS\) declares .* no such rule"
    ):
        frng_digests.check_rule_digests(cfg, {k: v for k, v in good.items() if k != "figures"})


# -- the workflow: one edit per stage, the dry run's job list ----------------------------------------------------

# the F-RNG models and everything made from them
FROM_TRAIN = {"train", "model_alias", "relight", "evaluate", "tables", "figures"}
# the baselines' scoring and tables, after anything they compare changed
BASELINE_SCORES = {"baseline_eval", "baseline_tables"}
RULES = {
    *("envmaps", "curate", "dataset_preview", "backbone_train", "idm_train", "backbone_cache", "idm_priors"),
    *("eval_backbone", "training_set_caches", "training_set_priors", "noise_floor"),
    *FROM_TRAIN,
    *("curate_baselines", "baseline_fit", "baseline_image", "baseline_frng_nvs", *BASELINE_SCORES),
}
# F-RNG's novel views (rule baseline_frng_nvs) come from the full model, the backbone and the IDM
AFTER_TRAIN = {*FROM_TRAIN, "baseline_frng_nvs", *BASELINE_SCORES}

# (key, new value) -> the rules whose jobs rerun ("all" left out); the smoke tier: learned IDM, 8 trained variants
CASES = [
    ("envmaps.normalize", 0.6, RULES),
    ("render.spp", 16, RULES - {"envmaps"}),
    (
        "backbone.train.steps",
        13,
        {"backbone_train", "backbone_cache", "training_set_caches", "eval_backbone", *AFTER_TRAIN},
    ),
    (
        "idm.train.steps",
        61,
        {"idm_train", "idm_priors", "training_set_priors", "eval_backbone", "baseline_image", *AFTER_TRAIN},
    ),
    ("train.steps", 21, AFTER_TRAIN),
    ("frng.hidden", 32, AFTER_TRAIN),
    # inference only: no retraining (the per-scene fits and the image-based baseline shade with it too)
    (
        "shading.spp_infer",
        64,
        {"relight", "evaluate", "tables", "figures", "baseline_fit", "baseline_image", "baseline_frng_nvs"}
        | BASELINE_SCORES,
    ),
    # a second training seed (`make seeds`): its models and their relighting, not the first seed's `relight` jobs
    ("train.seeds", [0, 1], {"train", "relight_seed", "evaluate", "tables", "figures"}),
    ("eval.protocol", "plain", {"evaluate", "noise_floor", "tables", "figures", *BASELINE_SCORES}),
    # the targets' noise floor (the ladder's step 0) alone: no curation, no model
    ("render.noise_floor.reference_spp", 32, {"noise_floor", "tables"}),
    ("tier", "custom", {"tables", "baseline_tables"}),
    # the fits, their scores and tables (the tables rule waits for them only where it writes the results page)
    ("baselines.fit.steps", 61, {"baseline_fit", *BASELINE_SCORES}),
]


def snakemake(configfile: Path, workdir: Path, *args) -> subprocess.CompletedProcess:
    cmd = [
        venv_bin("snakemake"),
        "--snakefile",
        str(ROOT / "workflow" / "Snakefile"),
        "--directory",
        str(workdir),
        "--configfile",
        str(configfile),
        *args,
    ]
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    proc = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=300, env=env)
    assert proc.returncode == 0, (proc.stdout + proc.stderr)[-4000:]
    return proc


def set_key(cfg: dict, dotted: str, value) -> dict:
    cfg = copy.deepcopy(cfg)
    *path, last = dotted.split(".")
    node = cfg
    for part in path:
        node = node.setdefault(part, {})
    node[last] = value
    return cfg


class Folder:
    """A smoke-tier results folder where every job has "run" (touched) with ``config``."""

    def __init__(self, tmp: Path):
        self.tmp, self.workdir, self.results = tmp, tmp / "workdir", tmp / "results"
        self.config = yaml.safe_load((ROOT / "config" / "smoke.yaml").read_text())
        self.config["results"] = str(self.results)
        path = self.write("done.yaml", self.config)
        self.workdir.mkdir()
        summary = snakemake(path, self.workdir, "--summary").stdout  # every planned output (all missing now)
        outputs = [Path(line.split("\t")[0]) for line in summary.splitlines()[1:] if line.strip()]
        assert len(outputs) > 50 and all(str(p).startswith(str(self.results)) for p in outputs)
        for p in outputs:  # directory() outputs (figures/comparison, figures/saliency) have no suffix
            if p.suffix:
                p.parent.mkdir(parents=True, exist_ok=True)
                p.touch()
            else:
                p.mkdir(parents=True, exist_ok=True)
        snakemake(path, self.workdir, "--touch", "--forceall", "--cores", "1")

    def write(self, name: str, cfg: dict) -> Path:
        path = self.tmp / name
        path.write_text(yaml.safe_dump(cfg, sort_keys=False))
        return path

    def jobs(self, cfg: dict, name: str) -> dict[str, int]:
        """Rule -> number of jobs a dry run with ``cfg`` would run ("all" and "total" left out)."""
        proc = snakemake(self.write(name, cfg), self.workdir, "-n", "--quiet", "rules")
        out = proc.stdout + proc.stderr
        if "Nothing to be done" in out:
            return {}
        counts = {}
        rules = {m.group(1): int(m.group(2)) for m in re.finditer(r"^(\w+)\s+(\d+)$", out, re.M)}
        for rule, n in rules.items():  # batched rules (backbone_cache_train0, ...) counted under their family
            counts[rule_family(rule)] = counts.get(rule_family(rule), 0) + n
        assert counts, out[-4000:]
        # config_digest / curate_record: the jobs writing each edited rule's digest file and each changed object's
        # curation record into the results folder (bookkeeping)
        return {r: n for r, n in counts.items() if r not in ("all", "total", "config_digest", "curate_record")}


@pytest.fixture(scope="module")
def folder(tmp_path_factory) -> Folder:
    return Folder(tmp_path_factory.mktemp("digests"))


def test_unchanged_config_reruns_nothing(folder):
    assert folder.jobs(folder.config, "same.yaml") == {}


@pytest.mark.parametrize("key, value, expected", CASES, ids=[c[0] for c in CASES])
def test_an_edit_reruns_its_rules_and_what_follows_only(folder, key, value, expected):
    jobs = folder.jobs(set_key(folder.config, key, value), f"{key}.yaml")
    assert set(jobs) == expected, (
        f"{key}: needless reruns {sorted(set(jobs) - expected)}, missing reruns {sorted(expected - set(jobs))}"
    )
    cfg = frng_config.load(folder.write("check.yaml", folder.config))
    n_test = cfg["objects"]["test_count"]
    # one job per batch of objects (rules/priors.smk), each split batched on its own
    n_batches = sum(len(batches(range(n), DEFAULT_BATCH_OBJECTS)) for n in (cfg["objects"]["count"] - n_test, n_test))
    if key == "backbone.train.steps":  # every cache and every variant
        assert jobs["backbone_cache"] == n_batches and jobs["train"] == len(trained_variants(cfg))
    if key == "idm.train.steps":  # every variant but no-idm, which reads no IDM prior
        assert jobs["idm_priors"] == n_batches and jobs["train"] == len(trained_variants(cfg)) - 1
    if key == "train.seeds":  # full and each ablation once more, relit per test object; no `relight` job
        assert jobs["train"] == len(seeded_bases(cfg)) and jobs["relight_seed"] == n_test


def _plans(folder: Folder, edited: dict):
    from frng.plan import catalog

    return (
        catalog.plan(frng_config.load(folder.write(n, c))) for n, c in (("p0.yaml", folder.config), ("p1.yaml", edited))
    )


def test_an_added_object_reruns_its_own_curation_only(folder, tmp_path):
    """A user's object added to the config has maps of its own (one per object and light): `frng envmaps` reruns
    and rewrites the index, but the other objects' curation (their plan entries and maps unchanged) does not."""
    mesh = tmp_path / "mine.obj"
    mesh.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nf 1 2 3\nf 1 2 4\nf 1 3 4\nf 2 3 4\n")
    edited = set_key(folder.config, "objects.extra", [{"path": str(mesh), "split": "train"}])
    before, after = _plans(folder, edited)
    assert [o.id for o in after.objects] == [o.id for o in before.objects] + ["user_mine"]
    assert all(after.object(o.id) == o for o in before.objects)  # (else those objects rerun, rightly)
    jobs = folder.jobs(edited, "added.yaml")
    assert jobs["envmaps"] == 1 and jobs["curate"] == 1, jobs
    # an object whose curation is missing is still curated in that run, asked for by name too (the index is ancient
    # only for an up-to-date curation: Snakemake 9.27 skips a job below a rerunning one by ancient files, whatever
    # its own reason)
    meta = folder.results / "objects" / before.objects[0].id / "meta.json"
    aside = meta.with_name("meta.json.aside")
    meta.rename(aside)
    try:
        jobs = folder.jobs(edited, "added_missing.yaml")
        named = snakemake(folder.write("named.yaml", edited), folder.workdir, "-n", "--quiet", "rules", "--", str(meta))
    finally:
        aside.rename(meta)
    assert jobs["envmaps"] == 1 and jobs["curate"] == 2, jobs
    assert re.search(r"^curate\s+1$", named.stdout + named.stderr, re.M), (named.stdout + named.stderr)[-3000:]


def test_a_light_edit_reruns_the_curation_of_the_objects_it_changes(folder):
    """envmaps.skies.sun_share changes the sky maps only: the objects with a sky draw rerun, the others stay."""
    from frng.plan import curate_jobs

    edited = set_key(folder.config, "envmaps.skies.sun_share", 0.5)
    before, after = _plans(folder, edited)
    changed = [
        o.id for o in before.objects if curate_jobs.curate_digest(before, o) != curate_jobs.curate_digest(after, o)
    ]
    skies = [o.id for o in before.objects if any(e.source == "sky" for e in curate_jobs.object_envmaps(before, o))]
    assert changed == skies and 0 < len(changed) < len(before.objects), (changed, skies)
    jobs = folder.jobs(edited, "sun_share.yaml")
    assert jobs["envmaps"] == 1 and jobs["curate"] == len(changed), jobs


def test_curate_records_are_written_and_replaced(tmp_path):
    from frng.plan import catalog, curate_jobs, dataset_config
    from frng.plan.layout import Layout

    cfg = frng_config.validate(yaml.safe_load((ROOT / "config" / "smoke.yaml").read_text()))
    L, plan = Layout(tmp_path), catalog.plan(cfg)
    spec = plan.objects[0]
    first = Path(L.curate_record(spec.id, curate_jobs.curate_digest(plan, spec)))
    curate_jobs.write_curate_record(plan, spec, first)
    record = yaml.safe_load(first.read_text())
    assert record["object"]["id"] == spec.id and [r["name"] for r in record["lights"]] == list(
        dict.fromkeys(spec.input_lights + spec.target_lights)
    )
    edited = catalog.plan(set_key(cfg, "seed", 1))
    second = Path(L.curate_record(spec.id, curate_jobs.curate_digest(edited, edited.object(spec.id))))
    curate_jobs.write_curate_record(edited, edited.object(spec.id), second)
    assert second != first and second.exists() and not first.exists()
    with pytest.raises(dataset_config.CatalogError, match="not the curation record"):
        curate_jobs.write_curate_record(plan, spec, second)


# -- the digests travel with the results folder (issue 24, item 2) -----------------------------------------------


@pytest.mark.parametrize("key, value", [("train.steps", 21), ("train.lr", 0.123)])
def test_a_copied_folder_keeps_the_rerun_promise(folder, tmp_path, key, value):
    """`cp -a` of a finished folder, planned from a fresh working directory (no .snakemake metadata): an edit still
    reruns every job of the rules that read the key (it used to answer "Nothing to be done" for train.steps, and
    rerun 1 of the 8 trainings for train.lr), and the unedited config still reruns nothing."""
    copy_ = tmp_path / "copy"
    subprocess.run(["cp", "-a", str(folder.results), str(copy_)], check=True)
    fresh = Folder.__new__(Folder)
    fresh.tmp, fresh.workdir, fresh.results = tmp_path, tmp_path / "workdir", copy_
    fresh.workdir.mkdir()
    fresh.config = {**folder.config, "results": str(copy_)}
    assert fresh.jobs(fresh.config, "same.yaml") == {}
    jobs = fresh.jobs(set_key(fresh.config, key, value), "edited.yaml")
    cfg = frng_config.load(fresh.write("check.yaml", fresh.config))
    assert set(jobs) == AFTER_TRAIN and jobs["train"] == len(trained_variants(cfg)), jobs
    assert sorted(p.name for p in (copy_ / ".digests").iterdir()) == sorted(
        p.name for p in (folder.results / ".digests").iterdir()
    )  # planning wrote nothing


def test_digest_files_are_recorded_and_replaced(tmp_path):
    from frng.plan.layout import Layout

    cfg = frng_config.validate(yaml.safe_load((ROOT / "config" / "smoke.yaml").read_text()))
    L = Layout(tmp_path)
    first = Path(L.rule_digest("train", frng_digests.rule_digest(cfg, "train")))
    frng_digests.write_rule_digest(cfg, "train", first)
    other_rule = tmp_path / ".digests" / "training_set_caches-0123abcd.txt"
    other_rule.write_text("{}")
    edited = set_key(cfg, "train.steps", 3)
    second = Path(L.rule_digest("train", frng_digests.rule_digest(edited, "train")))
    frng_digests.write_rule_digest(edited, "train", second)
    assert second != first and second.exists() and not first.exists() and other_rule.exists()
    assert yaml.safe_load(second.read_text())["values"]["train"]["steps"] == 3
    with pytest.raises(frng_config.ConfigError, match="not the digest file"):
        frng_digests.write_rule_digest(cfg, "train", second)
    # when jobs start, the digest files of other configs go (a --touch run leaves them)
    (tmp_path / ".digests" / "notes.txt").write_text("")
    assert frng_digests.remove_stale_digests(edited, L.digests_dir()) == [other_rule]
    assert second.exists() and (tmp_path / ".digests" / "notes.txt").exists()
