# Environment maps: one per (object, light) draw of the plan -- a base map of the light pool (Blender's bundled HDRIs,
# baked skies, procedural studios, users' maps) rotated by the draw's own angle, resized, normalised; split
# train/test by base map within each family. One job writes them all (~25 s for the default tier's 715 maps); see
# frng/data/envmaps.py.
ENVMAP_NAMES = [e.name for e in CATALOG.envmaps]
USER_ENVMAP_FILES = sorted({e.origin for e in CATALOG.envmaps if e.source == "user"})


rule envmaps:
    input:
        USER_ENVMAP_FILES,
    output:
        # the index only: the maps (one per object and light: 106k at the paper tier) as outputs made the paper DAG
        # plan for minutes; `frng envmaps` writes all or nothing, the index last, and curation checks every map
        index=L.envmap_index(),
    log:
        L.log("envmaps"),
    conda:
        "../envs/blender.yaml"
    threads: config["render"]["threads"]
    resources:
        mem_mb=3000,
        runtime=10 + len(ENVMAP_NAMES) // 300,  # ~0.04 s per map at 128 px; 0.2 s allowed
    params:
        **stage_params("envmaps"),
        out=lambda wildcards, output: os.path.dirname(output.index),
    message:
        "Preparing {n} environment maps".format(n=len(ENVMAP_NAMES))
    shell:
        "exec {params.py:q} -m frng envmaps --config {params.config:q} --out {params.out:q} > {log:q} 2>&1"


add_targets(L.envmap_index())
