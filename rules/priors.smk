# Frozen priors (frng/priors/): the RelitLRM-style backbone and the IDM are trained once on the TRAINING split,
# then cached per object (one job per object) so that F-RNG training reads caches only.
TRAIN_IDS = CATALOG.split("train")
_IDM_MODEL = [res("idm/model.pt")] if config["idm"]["kind"] == "learned" else []


rule backbone_train:
    message:
        "Training the backbone on {n} training objects".format(n=len(TRAIN_IDS))
    input:
        expand(res("objects/{obj}/meta.json"), obj=TRAIN_IDS),
    output:
        model=res("backbone/model.pt"),
        curve=res("backbone/loss.csv"),
        plot=res("backbone/loss.png"),
    params:
        config_digest=frng_config.rule_digest(config, "backbone_train"),
        out=lambda wildcards, output: os.path.dirname(output.model),
        py=PY,
        config=CONFIG_FILE,
    log:
        res("logs/backbone_train.log"),
    conda:
        "../envs/torch.yaml"
    threads: 2
    resources:
        mem_mb=6000,
        runtime=60,
        gpu=1,
    shell:
        "{params.py} -m frng backbone-train --config {params.config} --out {params.out} > {log} 2>&1"


rule idm_train:
    message:
        "Training the learned IDM on {n} training objects".format(n=len(TRAIN_IDS))
    input:
        expand(res("objects/{obj}/meta.json"), obj=TRAIN_IDS),
    output:
        model=res("idm/model.pt"),
        curve=res("idm/loss.csv"),
        plot=res("idm/loss.png"),
    params:
        config_digest=frng_config.rule_digest(config, "idm_train"),
        out=lambda wildcards, output: os.path.dirname(output.model),
        py=PY,
        config=CONFIG_FILE,
    log:
        res("logs/idm_train.log"),
    conda:
        "../envs/torch.yaml"
    threads: 2
    resources:
        mem_mb=4000,
        runtime=30,
        gpu=1,
    shell:
        "{params.py} -m frng idm-train --config {params.config} --out {params.out} > {log} 2>&1"


rule backbone_cache:
    message:
        "Caching backbone tokens of {wildcards.obj}"
    input:
        model=res("backbone/model.pt"),
        meta=res("objects/{obj}/meta.json"),
    output:
        res("backbone/cache/{obj}.safetensors"),
    params:
        config_digest=frng_config.rule_digest(config, "backbone_cache"),
        py=PY,
        config=CONFIG_FILE,
    log:
        res("logs/backbone_cache/{obj}.log"),
    wildcard_constraints:
        obj=r"[a-z0-9_]+",
    conda:
        "../envs/torch.yaml"
    threads: 1
    resources:
        mem_mb=3000,
        runtime=15,
        gpu=1,
    shell:
        "{params.py} -m frng backbone-cache --config {params.config} --object {wildcards.obj} "
        "--model {input.model} --out {output} > {log} 2>&1"


rule idm_priors:
    message:
        "IDM priors ({kind}) of {{wildcards.obj}}".format(kind=config["idm"]["kind"])
    input:
        model=_IDM_MODEL,
        meta=res("objects/{obj}/meta.json"),
    output:
        res("priors/idm/{obj}.safetensors"),
    params:
        config_digest=frng_config.rule_digest(config, "idm_priors"),
        py=PY,
        config=CONFIG_FILE,
    log:
        res("logs/idm_priors/{obj}.log"),
    wildcard_constraints:
        obj=r"[a-z0-9_]+",
    conda:
        "../envs/torch.yaml"
    threads: 1
    resources:
        mem_mb=2000,
        runtime=10,
        gpu=1,
    shell:
        "{params.py} -m frng idm-priors --config {params.config} --object {wildcards.obj} --out {output} > {log} 2>&1"


rule eval_backbone:
    message:
        "Evaluating the frozen priors on the test objects"
    input:
        backbone=res("backbone/model.pt"),
        idm=_IDM_MODEL,
        objects=expand(res("objects/{obj}/meta.json"), obj=CATALOG.object_ids),
    output:
        backbone=res("metrics/backbone.csv"),
        idm=res("metrics/idm.csv"),
    params:
        config_digest=frng_config.rule_digest(config, "eval_backbone"),
        py=PY,
        config=CONFIG_FILE,
    log:
        res("logs/eval_backbone.log"),
    conda:
        "../envs/torch.yaml"
    threads: 2
    resources:
        mem_mb=4000,
        runtime=30,
    shell:
        "{params.py} -m frng eval-backbone --config {params.config} --model {input.backbone} "
        "--backbone-csv {output.backbone} --idm-csv {output.idm} > {log} 2>&1"


add_targets(
    res("backbone/loss.png"),
    res("idm/loss.png"),
    res("metrics/backbone.csv"),
    res("metrics/idm.csv"),
    *expand(res("backbone/cache/{obj}.safetensors"), obj=CATALOG.object_ids),
    *expand(res("priors/idm/{obj}.safetensors"), obj=CATALOG.object_ids),
)
