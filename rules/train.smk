# F-RNG training (frng/stages/train.py, the training in frng/training/frng_trainer.py): one `train` job per variant and seed.
from frng.plan.variants import (
    all_variants,
    canonical_variant,
    reads_priors,
    split_seed,
    torchrun_command,
    trained_variants,
)

FRNG_TRAINED = trained_variants(config)
FRNG_ALIASES = [v for v in all_variants(config) if canonical_variant(config, v) != v]


# The train jobs read the training split through two index files, so that the paper DAG plans fast.


rule training_set_caches:
    input:
        caches=expand(L.backbone_cache(), obj=TRAIN_IDS),
        meta=expand(rules.curate.output.meta, obj=TRAIN_IDS),
    output:
        L.backbone_cache_index(),
    log:
        L.log("training_set_caches"),
    localrule: True
    params:
        **digest_params("training_set_caches"),
    message:
        "Index of the training split's backbone caches and curated objects ({n} objects)".format(n=len(TRAIN_IDS))
    run:
        from frng.io import write_file_index

        write_file_index([*input.caches, *input.meta], output[0], log[0], split="train", objects=TRAIN_IDS)


rule training_set_priors:
    input:
        priors=expand(L.idm_priors(), obj=TRAIN_IDS),
    output:
        L.idm_priors_index(),
    log:
        L.log("training_set_priors"),
    localrule: True
    params:
        **digest_params("training_set_priors"),
    message:
        "Index of the training split's IDM priors ({n} objects)".format(n=len(TRAIN_IDS))
    run:
        from frng.io import write_file_index

        write_file_index(input.priors, output[0], log[0], split="train", objects=TRAIN_IDS)


rule train:
    input:
        backbone=rules.backbone_train.output.model,
        caches=rules.training_set_caches.output[0],
        priors=lambda wildcards: rules.training_set_priors.output[0] if reads_priors(wildcards.variant) else [],
    output:
        model=L.model(),
        curve=L.model_curve(),
        plot=L.model_curve(ext="png"),
    log:
        L.model_file("{variant}", "train.log"),
    wildcard_constraints:
        variant="|".join(re.escape(v) for v in FRNG_TRAINED),
    # the models' seed first (2), other seeds next (1), relighting last (0): relighting fills cores trainings leave idle
    priority: lambda wildcards: 1 if split_seed(wildcards.variant)[1] is not None else 2
    conda:
        "../envs/torch.yaml"
    # one thread: two 1-thread trainings side by side beat one 2-thread training; clusters set their own
    threads: 1
    resources:
        mem_mb=6000,
        runtime=60,
        gpu=TORCH_GPUS,
    params:
        **stage_params("train", py=False),
        out=lambda wildcards, output: os.path.dirname(output.model),
        launcher=lambda wildcards, resources: torchrun_command(resources.gpu, python=PY),
    message:
        "Training F-RNG variant {wildcards.variant}"
    shell:
        "exec {params.launcher} train --config {params.config:q} --variant {wildcards.variant:q} "
        "--backbone {input.backbone:q} --out {params.out:q} > {log:q} 2>&1"


rule model_alias:
    input:
        model=L.model("full"),
        curve=L.model_curve("full"),
        plot=L.model_curve("full", "png"),
    output:
        model=L.model("{alias}"),
        curve=L.model_curve("{alias}"),
        plot=L.model_curve("{alias}", "png"),
    log:
        L.model_file("{alias}", "alias.log"),
    wildcard_constraints:
        alias="|".join(re.escape(v) for v in FRNG_ALIASES) if FRNG_ALIASES else "(?!)",
    localrule: True
    conda:
        "../envs/eval.yaml"
    threads: 1
    resources:
        mem_mb=500,
        runtime=5,
    params:
        **digest_params("model_alias"),
    message:
        "F-RNG variant {wildcards.alias} is the full model (same K): copying it"
    shell:
        "(cp {input.model:q} {output.model:q} && cp {input.curve:q} {output.curve:q} && cp {input.plot:q} {output.plot:q}) "
        "> {log:q} 2>&1"


add_targets(*expand(L.model(), variant=FRNG_VARIANTS))
