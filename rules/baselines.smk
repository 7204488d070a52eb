# The paper's Tables 2 and 3 and its views table (frng/baselines/): per-scene baselines fitted on dense views
# (3dgs, gsir), an image-based baseline, other methods' outputs read from files, scored beside F-RNG.
# rule curate_baselines: ONE Blender process per test object renders its target views under its first input light
# (the image-based methods' input; the novel-view ground truth) and, for the per-scene baselines' objects
# (baselines.objects_per_class per material class), render.dense_views views on a sphere under that light.
from frng.baselines import plan as frng_baselines

frng_baselines.check_view_counts(config)
BASELINE_OBJECTS = frng_baselines.baseline_objects(config, frng_baselines.test_objects(CATALOG))
_BASELINES = config.get("baselines", {})
# the extra views are rendered for every test object when the image-based baseline runs, else for the per-scene ones
BASELINE_VIEW_IDS = TEST_IDS if _BASELINES.get("image_based", True) and BASELINE_OBJECTS else BASELINE_OBJECTS


rule curate_baselines:
    input:
        unpack(lambda wildcards: frng_catalog.curate_inputs(config, CATALOG.object(wildcards.obj))),
        meta=rules.curate.output.meta,
    output:
        meta=L.baseline_views_meta(),
    log:
        L.log("curate_baselines", "{obj}"),
    wildcard_constraints:
        obj=r"[a-z0-9_]+",
    conda:
        "../envs/blender.yaml"
    threads: _RENDER["threads"]
    resources:
        mem_mb=2500,
        runtime=lambda wildcards: frng_catalog.curate_minutes(config, CATALOG.object(wildcards.obj)),
    params:
        **stage_params("curate_baselines"),
        envmaps=lambda wildcards, input: os.path.dirname(input.index),
        out=lambda wildcards, output: os.path.dirname(os.path.dirname(output.meta)),  # {views}/{obj}/meta.json
    message:
        "Baselines' views of {wildcards.obj}: target views under its input light (+ dense views)"
    shell:
        "exec {params.py:q} -m frng curate-baselines --config {params.config:q} --object {wildcards.obj:q} "
        "--envmaps {params.envmaps:q} --meta {input.meta:q} --out {params.out:q} > {log:q} 2>&1"


add_targets(*expand(L.baseline_views_meta(), obj=BASELINE_VIEW_IDS))
