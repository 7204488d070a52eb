# F-RNG training (stage frng/stages/train.py, the training itself in frng/training/frng_trainer.py): one `train` job per
# variant, reading the frozen priors' caches only.
# The K-sweep entry equal to the full model's K (k2 with the paper's 2%) is the full model: `model_alias` copies it
# into its own folder instead of training it twice.
# Other training seeds (train.seeds) are variants too: `full@s1`, `no-fine@s1`, ... (frng/plan/variants.py), each its own
# `train` job with train_seed = 1 (the stage reads the suffix); the K sweep is not repeated per seed.
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


# The train jobs depend on the training split through two indexes (rules training_set_*): the 8 training jobs of
# the paper tier listing ~2700 per-object files each dominated the paper DAG's planning time.


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
    # the models' seed first (2), then the other seeds (1), both before the relighting jobs (0): the first seed's
    # relighting (rule relight) then fills the core the other seeds' last training leaves idle (13 trainings on 2
    # cores at the default tier: the last one ran alone for ~6 min while relighting waited for every model)
    priority: lambda wildcards: 1 if split_seed(wildcards.variant)[1] is not None else 2
    conda:
        "../envs/torch.yaml"
    # one thread: on a 2-core machine two trainings side by side at one thread each finish 8 variants ~20% sooner
    # than one after another at two (measured: 1.6 + 1.6 vs 2.5 steps/s); clusters set their own (profiles/slurm)
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
