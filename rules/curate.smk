# Curation: ONE Blender process per object renders its input views x input lights, target views x target
# lights and the G-buffers (frng/data/curate.py); then one job draws a contact sheet per object.
OBJECT_IDS = CATALOG.object_ids
_RENDER = config["render"]


rule curate:
    input:
        unpack(lambda wildcards: frng_catalog.curate_inputs(config, CATALOG.object(wildcards.obj))),
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
        runtime=lambda wildcards: frng_catalog.curate_minutes(config, CATALOG.object(wildcards.obj)),
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


add_targets(*expand(L.object_meta(), obj=OBJECT_IDS), *expand(L.preview(), obj=OBJECT_IDS))
