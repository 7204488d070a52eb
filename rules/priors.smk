# Frozen priors (docs/priors.md): trained once on the training split, then cached per object for F-RNG's training.


rule backbone_train:
    input:
        expand(rules.curate.output.meta, obj=TRAIN_IDS),
    output:
        model=L.backbone_model(),
        curve=L.backbone_curve(),
        plot=L.backbone_curve("png"),
    log:
        L.log("backbone_train"),
    conda:
        "../envs/torch.yaml"
    # one thread on a CPU: the same weights every time (docs/provenance-and-reproducibility.md)
    threads: 1
    resources:
        mem_mb=6000,
        runtime=60,
        gpu=TORCH_GPUS,
    params:
        **stage_params("backbone_train"),
        out=lambda wildcards, output: os.path.dirname(output.model),
    message:
        "Training the backbone on {n} training objects".format(n=len(TRAIN_IDS))
    shell:
        "exec {params.py:q} -m frng backbone-train --config {params.config:q} --out {params.out:q} > {log:q} 2>&1"


rule idm_train:
    input:
        expand(rules.curate.output.meta, obj=TRAIN_IDS),
    output:
        model=L.idm_model(),
        curve=L.idm_curve(),
        plot=L.idm_curve("png"),
    log:
        L.log("idm_train"),
    conda:
        "../envs/torch.yaml"
    threads: 1  # as backbone_train: reproducible weights; the two trainings run side by side on two cores
    resources:
        mem_mb=4000,
        runtime=30,
        gpu=TORCH_GPUS,
    params:
        **stage_params("idm_train"),
        out=lambda wildcards, output: os.path.dirname(output.model),
    message:
        "Training the learned IDM on {n} training objects".format(n=len(TRAIN_IDS))
    shell:
        "exec {params.py:q} -m frng idm-train --config {params.config:q} --out {params.out:q} > {log:q} 2>&1"


# One rule per batch of objects ({family}_{batch}: frng/plan/batches.py), every object's file its own output.
for _batch, _objs in PRIOR_BATCHES.items():

    rule:
        name:
            f"backbone_cache_{_batch}"
        input:
            model=rules.backbone_train.output.model,
            meta=expand(L.object_meta(), obj=_objs),
        output:
            caches=expand(L.backbone_cache(), obj=_objs),
        log:
            L.log("backbone_cache", _batch),
        conda:
            "../envs/torch.yaml"
        threads: 1
        resources:
            mem_mb=3000,
            runtime=lambda wildcards, attempt, n=len(_objs): (10 + 5 * n) * attempt,
            gpu=TORCH_GPUS,
        params:
            **stage_params("backbone_cache"),
            objects=_objs,
        message:
            f"Caching backbone tokens of {len(_objs)} objects (batch {_batch})"
        shell:
            "exec {params.py:q} -m frng backbone-cache --config {params.config:q} --object {params.objects:q} "
            "--model {input.model:q} --out {output.caches:q} > {log:q} 2>&1"

    rule:
        name:
            f"idm_priors_{_batch}"
        input:
            model=IDM_MODEL,
            meta=expand(L.object_meta(), obj=_objs),
        output:
            priors=expand(L.idm_priors(), obj=_objs),
        log:
            L.log("idm_priors", _batch),
        conda:
            "../envs/torch.yaml"
        threads: 1
        resources:
            mem_mb=2000,
            runtime=lambda wildcards, attempt, n=len(_objs): (10 + 3 * n) * attempt,
            gpu=TORCH_GPUS,
        params:
            **stage_params("idm_priors"),
            objects=_objs,
        message:
            f"IDM priors ({config['idm']['kind']}) of {len(_objs)} objects (batch {_batch})"
        shell:
            "exec {params.py:q} -m frng idm-priors --config {params.config:q} --object {params.objects:q} "
            "--out {output.priors:q} > {log:q} 2>&1"

    inherit_profile_settings(f"backbone_cache_{_batch}")
    inherit_profile_settings(f"idm_priors_{_batch}")


rule eval_backbone:
    input:
        backbone=rules.backbone_train.output.model,
        idm=IDM_MODEL,
        objects=expand(rules.curate.output.meta, obj=CATALOG.object_ids),
    output:
        backbone=L.metrics("backbone"),
        idm=L.metrics("idm"),
    log:
        L.log("eval_backbone"),
    conda:
        "../envs/torch.yaml"
    threads: 2
    resources:
        mem_mb=4000,
        runtime=30,
    params:
        **stage_params("eval_backbone"),
    message:
        "Evaluating the frozen priors on the test objects"
    shell:
        "exec {params.py:q} -m frng eval-backbone --config {params.config:q} --model {input.backbone:q} "
        "--backbone-csv {output.backbone:q} --idm-csv {output.idm:q} > {log:q} 2>&1"


add_targets(
    L.backbone_curve("png"),
    L.idm_curve("png"),
    L.metrics("backbone"),
    L.metrics("idm"),
    *expand(L.backbone_cache(), obj=CATALOG.object_ids),
    *expand(L.idm_priors(), obj=CATALOG.object_ids),
)
