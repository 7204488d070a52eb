# Curation (docs/dataset-and-curation.md): ONE Blender process per object renders all its views, lights and G-buffers.
OBJECT_IDS = CATALOG.object_ids
_RENDER = config["render"]


# A record file named by the object's plan digest, so that a changed plan reruns its curation in a copied folder too.
rule curate_record:
    output:
        L.curate_record(),
    log:
        L.log("curate_record", "{obj}-{digest}"),
    wildcard_constraints:
        obj=r"[a-z0-9_]+",
        digest=r"[0-9a-f]+",
    localrule: True
    message:
        "Curation record of {wildcards.obj}: {wildcards.digest}"
    run:
        write_curate_record(wildcards.obj, output[0], log[0])


rule curate:
    input:
        unpack(curation_inputs("curate", L.object_meta)),
    output:
        meta=L.object_meta(),
    log:
        L.log("curate", "{obj}"),
    wildcard_constraints:
        obj=r"[a-z0-9_]+",
    conda:
        "../envs/blender.yaml"
    threads: _RENDER["threads"]
    resources:
        mem_mb=2500,
        runtime=lambda wildcards: frng_curate_jobs.curate_minutes(config, CATALOG.object(wildcards.obj)),
    params:
        **stage_params("curate"),
        spec=lambda wildcards: json.dumps(CATALOG.object(wildcards.obj).to_dict(), sort_keys=True),
        envmaps=lambda wildcards, input: os.path.dirname(input.index),
        objects=lambda wildcards, output: os.path.dirname(os.path.dirname(output.meta)),  # {objects}/{obj}/meta.json
    shell:
        "exec {params.py:q} -m frng curate --config {params.config:q} --object {wildcards.obj:q} "
        "--envmaps {params.envmaps:q} --out {params.objects:q} > {log:q} 2>&1"


rule dataset_preview:
    input:
        expand(rules.curate.output.meta, obj=OBJECT_IDS),
    output:
        expand(L.preview(), obj=OBJECT_IDS),
    log:
        L.log("dataset_preview"),
    conda:
        "../envs/blender.yaml"
    threads: 1
    resources:
        mem_mb=2000,
        runtime=5 + len(OBJECT_IDS) // 20,
    params:
        **stage_params("dataset_preview"),
        out=lambda wildcards, output: os.path.dirname(output[0]),
    message:
        "Contact sheets of {n} objects".format(n=len(OBJECT_IDS))
    shell:
        "exec {params.py:q} -m frng dataset preview --config {params.config:q} --out {params.out:q} > {log:q} 2>&1"


# The targets' noise floor (the ladder's step 0): one test object per class, as curated and at high spp.
NOISE_FLOOR = [L.metrics("noise_floor")] if _RENDER["noise_floor"]["views"] > 0 else []


rule noise_floor:
    input:
        index=L.envmap_index(),
    output:
        csv=L.metrics("noise_floor"),
    log:
        L.log("noise_floor"),
    conda:
        "../envs/blender.yaml"
    threads: _RENDER["threads"]
    resources:
        mem_mb=2500,
        runtime=30,
    params:
        **stage_params("noise_floor"),
        envmaps=lambda wildcards, input: os.path.dirname(input.index),
    message:
        "The targets' noise floor: {views} target view(s) of one test object per class against {spp}-spp renders".format(
            views=_RENDER["noise_floor"]["views"], spp=2 * _RENDER["noise_floor"]["reference_spp"]
        )
    shell:
        "exec {params.py:q} -m frng noise-floor --config {params.config:q} --envmaps {params.envmaps:q} "
        "--out {output.csv:q} > {log:q} 2>&1"


# the record files are targets too: Snakemake makes a missing input only for a job that runs anyway
add_targets(
    *expand(L.object_meta(), obj=OBJECT_IDS),
    *expand(L.preview(), obj=OBJECT_IDS),
    *(L.curate_record(o.id, frng_curate_jobs.curate_digest(CATALOG, o)) for o in CATALOG.objects),
    *NOISE_FLOOR,
)
