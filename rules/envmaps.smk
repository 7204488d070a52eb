# Environment maps (frng/data/envmaps.py): one job writes every map of the plan, split train/test by base map.
ENVMAP_NAMES = [e.name for e in CATALOG.envmaps]
USER_ENVMAP_FILES = sorted({e.origin for e in CATALOG.envmaps if e.source == "user"})


rule envmaps:
    input:
        USER_ENVMAP_FILES,
    output:
        # the index only, not one output per map (too many to plan); `frng envmaps` writes all or nothing
        index=L.envmap_index(),
    log:
        L.log("envmaps"),
    conda:
        "../envs/blender.yaml"
    threads: config["render"]["threads"]
    resources:
        mem_mb=3000,
        runtime=10 + len(ENVMAP_NAMES) // 300,  # about 0.2 s allowed per map
    params:
        **stage_params("envmaps"),
        out=lambda wildcards, output: os.path.dirname(output.index),
    message:
        "Preparing {n} environment maps".format(n=len(ENVMAP_NAMES))
    shell:
        "exec {params.py:q} -m frng envmaps --config {params.config:q} --out {params.out:q} > {log:q} 2>&1"


add_targets(L.envmap_index())
