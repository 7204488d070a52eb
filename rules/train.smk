# F-RNG training (frng/train.py): one `train` job per variant, reading the frozen priors' caches only.
# The K-sweep entry equal to the full model's K (k2 with the paper's 2%) is the full model: `model_alias` copies it
# into its own folder instead of training it twice.
import re

from frng.variants import all_variants, canonical_variant, reads_priors, torchrun_command, trained_variants

FRNG_TRAINED = trained_variants(config)
FRNG_ALIASES = [v for v in all_variants(config) if canonical_variant(config, v) != v]
FRNG_VARIANTS = all_variants(config)
# GPUs per training job: 0 on CPU (CPU clusters reject gpu > 0; see profiles/slurm-ci), else 1 (profiles raise it).
_TRAIN_GPUS = 0 if config.get("device", "auto") == "cpu" else 1


_TRAIN_IDS = CATALOG.split("train")
# The train jobs depend on the training split through two indexes (rules training_set_*): the 8 training jobs of
# the paper tier listing ~2700 per-object files each dominated the paper DAG's planning time.


rule training_set_caches:
    message:
        "Index of the training split's backbone caches and curated objects ({n} objects)".format(n=len(_TRAIN_IDS))
    input:
        caches=expand(res("backbone/cache/{obj}.safetensors"), obj=_TRAIN_IDS),
        meta=expand(res("objects/{obj}/meta.json"), obj=_TRAIN_IDS),
    output:
        res("backbone/cache/train_set.json"),
    params:
        config_digest=frng_config.rule_digest(config, "training_set_caches"),
    log:
        res("logs/training_set_caches.log"),
    localrule: True
    run:
        from frng.io import write_file_index

        write_file_index([*input.caches, *input.meta], output[0], log[0], split="train", objects=_TRAIN_IDS)


rule training_set_priors:
    message:
        "Index of the training split's IDM priors ({n} objects)".format(n=len(_TRAIN_IDS))
    input:
        priors=expand(res("priors/idm/{obj}.safetensors"), obj=_TRAIN_IDS),
    output:
        res("priors/idm/train_set.json"),
    params:
        config_digest=frng_config.rule_digest(config, "training_set_priors"),
    log:
        res("logs/training_set_priors.log"),
    localrule: True
    run:
        from frng.io import write_file_index

        write_file_index(input.priors, output[0], log[0], split="train", objects=_TRAIN_IDS)


rule train:
    message:
        "Training F-RNG variant {wildcards.variant}"
    input:
        backbone=res("backbone/model.pt"),
        caches=res("backbone/cache/train_set.json"),
        priors=lambda wildcards: res("priors/idm/train_set.json") if reads_priors(wildcards.variant) else [],
    output:
        model=res("models/{variant}/model.pt"),
        curve=res("models/{variant}/loss.csv"),
        plot=res("models/{variant}/loss.png"),
    params:
        config_digest=frng_config.rule_digest(config, "train"),
        out=lambda wildcards, output: os.path.dirname(output.model),
        launcher=lambda wildcards, resources: torchrun_command(resources.gpu, python=PY),
        config=CONFIG_FILE,
    log:
        res("models/{variant}/train.log"),
    wildcard_constraints:
        variant="|".join(re.escape(v) for v in FRNG_TRAINED),
    conda:
        "../envs/torch.yaml"
    threads: 2
    resources:
        mem_mb=6000,
        runtime=60,
        gpu=_TRAIN_GPUS,
    shell:
        "{params.launcher} train --config {params.config} --variant {wildcards.variant} "
        "--backbone {input.backbone} --out {params.out} > {log} 2>&1"


rule model_alias:
    message:
        "F-RNG variant {wildcards.alias} is the full model (same K): copying it"
    input:
        model=res("models/full/model.pt"),
        curve=res("models/full/loss.csv"),
        plot=res("models/full/loss.png"),
    output:
        model=res("models/{alias}/model.pt"),
        curve=res("models/{alias}/loss.csv"),
        plot=res("models/{alias}/loss.png"),
    params:
        config_digest=frng_config.rule_digest(config, "model_alias"),
    log:
        res("models/{alias}/alias.log"),
    wildcard_constraints:
        alias="|".join(re.escape(v) for v in FRNG_ALIASES) if FRNG_ALIASES else "(?!)",
    localrule: True
    conda:
        "../envs/eval.yaml"
    threads: 1
    resources:
        mem_mb=500,
        runtime=5,
    shell:
        "(cp {input.model} {output.model} && cp {input.curve} {output.curve} && cp {input.plot} {output.plot}) "
        "> {log} 2>&1"


add_targets(*expand(res("models/{variant}/model.pt"), variant=FRNG_VARIANTS))
