# Relighting (frng/apps/relight.py): one job per test object and seed, F-RNG and the backbone timed in the same job.
from frng.plan.variants import MAIN_GROUP, SEED_SEP, RunPlan, model_variants, seed_variant, seeded_bases

_RUN_PLAN = RunPlan.of(config)
RELIGHT_RUNS = [r.name for r in _RUN_PLAN.runs(group=MAIN_GROUP)]
# other training seeds: one relight_seed job per (object, seed); its runs are {variant}@s{seed}
RELIGHT_SEEDS = [g for g in _RUN_PLAN.groups() if g != MAIN_GROUP]
SEEDED_BASES = seeded_bases(config)


rule relight:
    input:
        models=expand(L.model(), variant=model_variants(config, MAIN_GROUP)),
        backbone=rules.backbone_train.output.model,
        idm=IDM_MODEL,
        meta=rules.curate.output.meta,
    output:
        runs=expand(L.relight_record("{run}", "{{obj}}"), run=RELIGHT_RUNS),
        timing=L.relight_timing(),
    log:
        L.log("relight", "{obj}"),
    wildcard_constraints:
        obj=r"[a-z0-9_]+",
    conda:
        "../envs/torch.yaml"
    threads: 1
    resources:
        mem_mb=6000,
        runtime=60,
        gpu=TORCH_GPUS,
    params:
        **stage_params("relight"),
        models=lambda wildcards, input: os.path.dirname(os.path.dirname(input.models[0])),
        group=MAIN_GROUP,
    message:
        "Relighting {wildcards.obj}: F-RNG runs and the backbone under every target light"
    shell:
        "exec {params.py:q} -m frng relight --config {params.config:q} --object {wildcards.obj:q} --models {params.models:q} "
        "--group {params.group:q} > {log:q} 2>&1"


rule relight_seed:
    input:
        models=lambda wildcards: [L.model(seed_variant(v, int(wildcards.seed))) for v in SEEDED_BASES],
        backbone=rules.backbone_train.output.model,
        idm=IDM_MODEL,
        meta=rules.curate.output.meta,
    output:
        runs=[L.relight_record(f"{v}{SEED_SEP}{{seed}}", "{obj}") for v in SEEDED_BASES],
    log:
        L.log("relight", f"{{obj}}{SEED_SEP}{{seed}}"),
    wildcard_constraints:
        obj=r"[a-z0-9_]+",
        seed="|".join(RELIGHT_SEEDS) if RELIGHT_SEEDS else "(?!)",
    conda:
        "../envs/torch.yaml"
    threads: 1
    resources:
        mem_mb=6000,
        runtime=60,
        gpu=TORCH_GPUS,
    params:
        **stage_params("relight_seed"),
        models=lambda wildcards, input: os.path.dirname(os.path.dirname(input.models[0])),
    message:
        "Relighting {wildcards.obj}: the F-RNG runs of training seed {wildcards.seed}"
    shell:
        "exec {params.py:q} -m frng relight-seed --config {params.config:q} --object {wildcards.obj:q} "
        "--models {params.models:q} --group {wildcards.seed:q} > {log:q} 2>&1"
