# Relighting of the held-out objects (frng/relight.py): ONE job per test object runs every F-RNG run (ablation
# variants, K sweep, #views sweep of the full model) and the backbone baseline, so that both are timed side by side
# in the same job and the paper-scale DAG grows by the number of test objects only. One thread per job: on the
# default tier's 2 cores two objects relight side by side (one object: 34 s at one thread, 28 s at two, on the
# project's machine), so the timings are taken beside another relighting job, both methods in the same job.
from frng.variants import model_variants, runs

RELIGHT_RUNS = [r.name for r in runs(config)]


rule relight:
    input:
        models=expand(L.model(), variant=model_variants(config)),
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
    message:
        "Relighting {wildcards.obj}: F-RNG runs and the backbone under every target light"
    shell:
        "exec {params.py:q} -m frng relight --config {params.config:q} --object {wildcards.obj:q} --models {params.models:q} "
        "> {log:q} 2>&1"
