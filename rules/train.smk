# F-RNG training (frng/train.py): one `train` job per variant, reading the frozen priors' caches only.
# The K-sweep entry equal to the full model's K (k2 with the paper's 2%) is the full model: `model_alias` copies it
# into its own folder instead of training it twice.
import re

from frng.distributed import torchrun_command
from frng.model.frng import all_variants, canonical_variant, trained_variants

FRNG_TRAINED = trained_variants(config)
FRNG_ALIASES = [v for v in all_variants(config) if canonical_variant(config, v) != v]
FRNG_VARIANTS = all_variants(config)
# GPUs per training job: 0 on CPU (CPU clusters reject gpu > 0; see profiles/slurm-ci), else 1 (profiles raise it).
_TRAIN_GPUS = 0 if config.get("device", "auto") == "cpu" else 1


def _train_inputs(wildcards):
    """Backbone + its caches of the training objects (+ IDM priors unless the variant has no prior path)."""
    ids = CATALOG.split("train")
    ins = {
        "backbone": res("backbone/model.pt"),
        "caches": expand(res("backbone/cache/{obj}.safetensors"), obj=ids),
        "meta": expand(res("objects/{obj}/meta.json"), obj=ids),
    }
    if wildcards.variant != "no-idm":
        ins["priors"] = expand(res("priors/idm/{obj}.safetensors"), obj=ids)
    return ins


rule train:
    message:
        "Training F-RNG variant {wildcards.variant}"
    input:
        unpack(_train_inputs),
    output:
        model=res("models/{variant}/model.pt"),
        curve=res("models/{variant}/loss.csv"),
        plot=res("models/{variant}/loss.png"),
    params:
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
    wildcard_constraints:
        alias="|".join(re.escape(v) for v in FRNG_ALIASES) if FRNG_ALIASES else "(?!)",
    localrule: True
    shell:
        "cp {input.model} {output.model} && cp {input.curve} {output.curve} && cp {input.plot} {output.plot}"


add_targets(*expand(res("models/{variant}/model.pt"), variant=FRNG_VARIANTS))
