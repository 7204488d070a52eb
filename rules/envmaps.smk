# Environment maps: Blender's bundled HDRIs + baked skies (+ users' maps), rotated, resized, normalised,
# split train/test by base map. One job writes them all (seconds); see frng/data/envmaps.py.
ENVMAP_NAMES = [e.name for e in CATALOG.envmaps]
USER_ENVMAP_FILES = sorted({e.origin for e in CATALOG.envmaps if e.source == "user"})


rule envmaps:
    input:
        USER_ENVMAP_FILES,
    output:
        index=L.envmap_index(),
        maps=expand(L.envmap(), env=ENVMAP_NAMES),
    log:
        L.log("envmaps"),
    conda:
        "../envs/blender.yaml"
    threads: config["render"]["threads"]
    resources:
        mem_mb=3000,
        runtime=10 + len(ENVMAP_NAMES) // 20,
    params:
        **stage_params("envmaps"),
        out=lambda wildcards, output: os.path.dirname(output.index),
    message:
        "Preparing {n} environment maps".format(n=len(ENVMAP_NAMES))
    shell:
        "exec {params.py:q} -m frng envmaps --config {params.config:q} --out {params.out:q} > {log:q} 2>&1"


add_targets(L.envmap_index())
