# Frozen priors (frng/priors/): the RelitLRM-style backbone and the IDM are trained once on the TRAINING split,
# then cached per object (one job per object) so that F-RNG training reads caches only.


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
    threads: 2
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
    threads: 2
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


rule backbone_cache:
    input:
        model=rules.backbone_train.output.model,
        meta=rules.curate.output.meta,
    output:
        cache=L.backbone_cache(),
    log:
        L.log("backbone_cache", "{obj}"),
    wildcard_constraints:
        obj=r"[a-z0-9_]+",
    conda:
        "../envs/torch.yaml"
    threads: 1
    resources:
        mem_mb=3000,
        runtime=15,
        gpu=TORCH_GPUS,
    params:
        **stage_params("backbone_cache"),
    message:
        "Caching backbone tokens of {wildcards.obj}"
    shell:
        "exec {params.py:q} -m frng backbone-cache --config {params.config:q} --object {wildcards.obj:q} "
        "--model {input.model:q} --out {output.cache:q} > {log:q} 2>&1"


rule idm_priors:
    input:
        model=IDM_MODEL,
        meta=rules.curate.output.meta,
    output:
        priors=L.idm_priors(),
    log:
        L.log("idm_priors", "{obj}"),
    wildcard_constraints:
        obj=r"[a-z0-9_]+",
    conda:
        "../envs/torch.yaml"
    threads: 1
    resources:
        mem_mb=2000,
        runtime=10,
        gpu=TORCH_GPUS,
    params:
        **stage_params("idm_priors"),
    message:
        "IDM priors ({kind}) of {{wildcards.obj}}".format(kind=config["idm"]["kind"])
    shell:
        "exec {params.py:q} -m frng idm-priors --config {params.config:q} --object {wildcards.obj:q} --out {output.priors:q} > {log:q} 2>&1"


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
