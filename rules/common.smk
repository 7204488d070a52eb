# Shared helpers: config validation, object/light lists, output paths.
import json
import os
import re
import sys
from pathlib import Path

sys.path.insert(0, str(Path(workflow.basedir).parent))  # import frng without installing (conda users)

from snakemake.logging import logger
from snakemake_interface_executor_plugins.settings import ExecMode

from frng.plan import batches as frng_batches
from frng.plan import config as frng_config
from frng.plan import digests as frng_digests
from frng.plan import catalog as frng_catalog
from frng.plan import curate_jobs as frng_curate_jobs
from frng.plan import dataset_config as frng_dataset_config
from frng.plan.layout import Layout
from frng.plan.variants import all_variants

try:
    # `--config overwrite_config=true`: replace the results folder's recorded config (not part of the config)
    OVERWRITE_CONFIG = frng_config.pop_switch(config)
    for _configfile in workflow.configfiles:  # Snakemake's YAML reader keeps a key given twice silently
        frng_config.read_yaml(_configfile)
    frng_config.validate(config)
except frng_config.ConfigError as e:
    raise WorkflowError(f"invalid config: {e}")
try:
    # `--config priors_batch=N`: objects per job of the batched prior rules (frng/plan/batches.py; not part of the config)
    PRIORS_BATCH = frng_batches.batch_size(config)
except ValueError as e:
    raise WorkflowError(str(e))

RESULTS = config["results"]
L = Layout(RESULTS)  # every artefact's path (frng/plan/layout.py); rules pass their wildcards through
ROOT = Path(workflow.basedir).parent
# The effective config, recorded when jobs start (never by planning), so that a run with another config is refused.
CONFIG_FILE = L.config()


def effective_config_notice():
    """While planning: say whether this config matches the one recorded in the results folder (a dry run shows
    the refusal a real run would meet). Prints nothing when they match or none is recorded."""
    try:
        recorded = frng_config.read_recorded(CONFIG_FILE)
    except frng_config.ConfigError as e:
        logger.warning(f"NOTE: recorded config: {e}. A run is refused unless {frng_config.OVERWRITE_SWITCH}=true.")
        return
    if recorded is None:
        return
    diff = frng_config.differences(recorded, config)
    if diff and not OVERWRITE_CONFIG:
        logger.warning(f"NOTE: {frng_config.refusal(CONFIG_FILE, diff)}. A run with this config is refused.")
    elif diff:
        logger.warning(
            f"NOTE: {CONFIG_FILE} records a different config ({len(diff)} key(s) differ); a run "
            f"replaces it ({frng_config.OVERWRITE_SWITCH}=true)."
        )


if workflow.exec_mode == ExecMode.DEFAULT:  # not inside a job's own snakemake process (cluster/subprocess jobs)
    effective_config_notice()


def lock_results_folder():
    """Lock ``{results}/.lock`` (fcntl, held until this process exits) so that a second snakemake on the same
    results folder, from any working directory (Snakemake's own lock lives in the working directory's .snakemake),
    stops before its first job instead of rerunning what the first one is writing."""
    import fcntl

    path = Path(L.lock())
    try:
        frng_config.check_writable(path.parent)  # a read-only results folder: one line, as the config record says
        path.parent.mkdir(parents=True, exist_ok=True)
        fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o666)
    except (frng_config.ConfigError, OSError) as e:
        raise WorkflowError(str(e) if isinstance(e, frng_config.ConfigError) else f"cannot write {path}: {e.strerror}")
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError:
        holder = Path(path).read_text().strip() or "another process"
        os.close(fd)
        raise WorkflowError(
            f"{RESULTS} is in use by another snakemake run ({holder}; lock {path}); wait for it "
            f"to finish or stop it"
        )
    os.ftruncate(fd, 0)
    os.write(fd, f"pid {os.getpid()} on {os.uname().nodename}, working directory {os.getcwd()}\n".encode())
    return fd  # kept open: the lock lasts as long as this snakemake


onstart:
    # Jobs are about to run: lock the results folder, record the effective config, or refuse a differing one.
    RESULTS_LOCK = lock_results_folder()
    try:
        outcome = frng_config.record(config, CONFIG_FILE, overwrite=OVERWRITE_CONFIG)
    except frng_config.ConfigError as e:
        raise WorkflowError(str(e))
    frng_digests.remove_stale_digests(config, L.digests_dir())  # other configs' digest files (rule config_digest)
    if outcome != "unchanged":
        logger.info(f"effective config {outcome}: {CONFIG_FILE}")


# A generated batch rule's family (backbone_cache_train0 -> backbone_cache): digests and profile settings go by it.
rule_family = frng_batches.rule_family


def inherit_profile_settings(name):
    """Give generated batch rule `name` what the profile sets for its family (`set-threads`, `set-resources`, e.g.
    profiles/slurm's GPU partition for backbone_cache), unless the profile names the batch rule itself."""
    rs, family, r = workflow.resource_settings, rule_family(name), workflow.get_rule(name)
    threads = rs.overwrite_threads  # ResourceSettings' public fields: {rule: threads}, {rule: {resource: value}}
    if family in threads and name not in threads:
        r.resources["_cores"] = threads[family]
    resources = rs.overwrite_resources
    for key in (family, name):  # the batch rule's own entry last
        if key in resources:
            r.resources.update(resources[key])


# Every job reads its rule's digest file, so that the digests travel with the results folder (rules/digests.smk).
def digest_rules(rules):
    return [
        r
        for r in rules
        if r.name not in frng_digests.RULES_WITHOUT_DIGEST and rule_family(r.name) in frng_digests.RULE_CONFIG_KEYS
    ]


def add_digest_inputs(rules):
    """Make every rule with a config digest read its digest file (called once every rule file is included);
    returns the digest files, which `rule all` asks for (Snakemake makes a missing input only for a job that runs
    anyway: the target makes it run, and then every job reading it)."""
    files = []
    for r in digest_rules(rules):
        path = L.rule_digest(rule_family(r.name), frng_digests.rule_digest(config, rule_family(r.name)))
        r.set_input(config_digest=path)
        files.append(path)
    return sorted(set(files))


# Python running the stages: the interpreter snakemake runs in (the project's venv) unless --sdm conda.
PY = sys.executable


def digest_params(rule):
    """The `params:` entry every rule declares, `config_digest` (the digest of the config keys its stage reads,
    frng/plan/digests.py), so that Snakemake's params trigger reruns its jobs when one of them changes (rules/digests.smk
    writes the same digest beside the results). Used as `**digest_params(name)`."""
    return {"config_digest": frng_digests.rule_digest(config, rule)}


def stage_params(rule, *, py=True):
    """The `params:` entries of every stage-running rule (`exec {params.py} -m frng <stage> --config {params.config}`),
    used as `**stage_params(name)` before the rule's own: `config_digest`, `py` (the Python running the stages;
    py=False where the rule has its own launcher) and `config` (the effective config file)."""
    return {**digest_params(rule), **({"py": PY} if py else {}), "config": CONFIG_FILE}


# Shared state of the rule files (defined here so that include order does not matter).
try:
    CATALOG = frng_catalog.plan(config)  # the dataset plan: env maps, objects, splits, lights (no bpy, fast)
except frng_dataset_config.CatalogError as e:
    raise WorkflowError(f"invalid dataset plan: {e}")
TRAIN_IDS = CATALOG.split("train")
TEST_IDS = CATALOG.split("test")
REAL_TEST_IDS = CATALOG.real_assets("test")  # the test objects that are real assets (the real-objects figure)
# Batch name -> objects, per split (train0, train1, ..., test0): one job per batch for backbone_cache and idm_priors
PRIOR_BATCHES = frng_batches.object_batches({"train": TRAIN_IDS, "test": TEST_IDS}, PRIORS_BATCH)
# GPUs per torch job: 0 on CPU (CPU clusters reject gpu > 0; see profiles/slurm-ci), else 1 (profiles raise it).
TORCH_GPUS = 0 if config.get("device", "auto") == "cpu" else 1
IDM_MODEL = [L.idm_model()] if config["idm"]["kind"] == "learned" else []  # the learned IDM, when there is one
FRNG_VARIANTS = all_variants(config)  # every F-RNG variant the config asks for (frng/plan/variants.py)


def _up_to_date(output, inputs):
    """Whether `output` exists and is at least as new as every existing file of `inputs` (missing ones are made by
    jobs that run, and rerun it through them)."""
    out = Path(output)
    if not out.exists():
        return False
    t = out.stat().st_mtime
    return all(not Path(f).exists() or Path(f).stat().st_mtime <= t for f in inputs)


def curation_inputs(rule_name, output):
    """Input function of rules curate and curate_baselines (`output`: the job's meta.json). The env-map index orders
    the job after `frng envmaps`; where the job is otherwise up to date it is ancient, so its rewrite (whenever any
    object's maps change, e.g. an object added) reruns nothing: what the object's own maps are is its record file
    (rule curate_record) and the rule's digest (envmaps.width, envmaps.normalize), frng.plan.curate_jobs.curate_inputs.
    Ancient only then: Snakemake 9.27 never plans a job that hangs below a rerunning job by ancient files alone,
    whatever its own reason (a missing output, a newer input)."""

    def inputs(wildcards):
        spec = CATALOG.object(wildcards.obj)
        got = frng_curate_jobs.curate_inputs(config, spec)
        own = [f for k, v in got.items() if k != "index" for f in ([v] if isinstance(v, str) else v)]
        own.append(L.rule_digest(rule_name, frng_digests.rule_digest(config, rule_name)))
        if rule_name == "curate_baselines":
            own.append(L.object_meta(wildcards.obj))
        if _up_to_date(output(wildcards.obj), own):
            got["index"] = ancient(got["index"])
        return got

    return inputs


def write_curate_record(obj, path, log):
    """Rule curate_record's job: the object's record file (frng.plan.curate_jobs.write_curate_record) and its log line."""
    frng_curate_jobs.write_curate_record(CATALOG, CATALOG.object(obj), path)
    Path(log).write_text(f"recorded {path}\n")


_TARGETS = []


def add_targets(*paths):
    """Stage rule files register what `rule all` should build."""
    _TARGETS.extend(paths)


def all_targets():
    return list(_TARGETS)
