# Tables 2-3 and the views table (docs/baselines.md): per-scene, image-based and external baselines beside F-RNG.
from frng.baselines import plan as frng_baselines

try:  # baselines.view_counts and baselines.methods (frng/baselines/registry.py), checked once, in one line
    frng_baselines.check_view_counts(config)
    _PER_SCENE = frng_baselines.per_scene_methods(config)
except ValueError as e:
    raise WorkflowError(f"invalid config: {e}")
BASELINE_OBJECTS = frng_baselines.baseline_objects(config, frng_baselines.test_objects(CATALOG))
_BASELINES = config.get("baselines", {})
# the extra views are rendered for every test object when the image-based baseline runs, else for the per-scene ones
BASELINE_VIEW_IDS = TEST_IDS if _BASELINES.get("image_based", True) and BASELINE_OBJECTS else BASELINE_OBJECTS


# rule curate_baselines: one Blender process per object renders its target views under its input light (+ dense views).
rule curate_baselines:
    input:
        unpack(curation_inputs("curate_baselines", L.baseline_views_meta)),  # (rules/common.smk)
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
        runtime=lambda wildcards: frng_curate_jobs.curate_minutes(config, CATALOG.object(wildcards.obj)),
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


# rule baseline_fit: one job per (method, object) fits every view count, so the DAG grows by methods x objects only.
PER_SCENE_RUNS = frng_baselines.per_scene_runs(config)
VIEW_COUNTS = frng_baselines.view_counts(config)
PER_SCENE_METHODS = [m.name for m in _PER_SCENE] if PER_SCENE_RUNS else []


rule baseline_fit:
    input:
        views=L.baseline_views_meta(),
        meta=rules.curate.output.meta,
        index=L.envmap_index(),
    output:
        records=[L.relight_record(f"{{method}}-v{n}", "{obj}") for n in VIEW_COUNTS],
    log:
        L.log("baseline_fit", "{method}-{obj}"),
    wildcard_constraints:
        obj=r"[a-z0-9_]+",
        method="|".join(PER_SCENE_METHODS) or r"(?!x)x",
    conda:
        "../envs/torch.yaml"
    threads: 1
    resources:
        mem_mb=4000,
        runtime=30 * len(VIEW_COUNTS),
        gpu=TORCH_GPUS,
    params:
        **stage_params("baseline_fit"),
        views=" ".join(str(n) for n in VIEW_COUNTS),
        # {runs}/{run}/{obj}/run.json
        runs=lambda wildcards, output: os.path.dirname(os.path.dirname(os.path.dirname(output.records[0]))),
    message:
        "Per-scene baseline {wildcards.method} on {wildcards.obj}: {params.views} views"
    shell:
        "(for n in {params.views}; do {params.py:q} -m frng baseline-fit --config {params.config:q} "
        "--object {wildcards.obj:q} --method {wildcards.method:q} --views $n "
        '--out "{params.runs}/{wildcards.method}-v$n/{wildcards.obj}" || exit 1; done) > {log:q} 2>&1'


# rule baseline_image: the IDM re-shading baseline, one job per test object.
rule baseline_image:
    input:
        views=L.baseline_views_meta(),
        meta=rules.curate.output.meta,
        idm=IDM_MODEL,
        index=L.envmap_index(),
    output:
        record=L.relight_record(frng_baselines.IMAGE_BASED_RUN, "{obj}"),
    log:
        L.log("baseline_image", "{obj}"),
    wildcard_constraints:
        obj=r"[a-z0-9_]+",
    conda:
        "../envs/torch.yaml"
    threads: 1
    resources:
        mem_mb=4000,
        runtime=30,
        gpu=TORCH_GPUS,
    params:
        **stage_params("baseline_image"),
        out=lambda wildcards, output: os.path.dirname(output.record),
    message:
        "Image-based baseline on {wildcards.obj}"
    shell:
        "exec {params.py:q} -m frng baseline-image --config {params.config:q} --object {wildcards.obj:q} "
        "--out {params.out:q} > {log:q} 2>&1"


# rule baseline_frng_nvs: F-RNG's novel views under the input light, the views table's reference column.
rule baseline_frng_nvs:
    input:
        model=L.model("full"),
        backbone=rules.backbone_train.output.model,
        idm=IDM_MODEL,
        meta=rules.curate.output.meta,
        views=L.baseline_views_meta(),
    output:
        record=L.relight_record(frng_baselines.FRNG_NVS_RUN, "{obj}"),
    log:
        L.log("baseline_frng_nvs", "{obj}"),
    wildcard_constraints:
        obj=r"[a-z0-9_]+",
    conda:
        "../envs/torch.yaml"
    threads: 1
    resources:
        mem_mb=6000,
        runtime=30,
        gpu=TORCH_GPUS,
    params:
        **stage_params("baseline_frng_nvs"),
        out=lambda wildcards, output: os.path.dirname(output.record),
    message:
        "F-RNG's novel views of {wildcards.obj} under its input light"
    shell:
        "exec {params.py:q} -m frng baseline-frng-nvs --config {params.config:q} --object {wildcards.obj:q} "
        "--out {params.out:q} > {log:q} 2>&1"


_IMAGE_RUN_IDS = BASELINE_VIEW_IDS if _BASELINES.get("image_based", True) else []


# rule baseline_eval: every baseline image and F-RNG's scored per image under eval.protocol
rule baseline_eval:
    input:
        frng=expand(L.relight_record("full", "{obj}"), obj=TEST_IDS),
        timing=expand(rules.relight.output.timing, obj=TEST_IDS),
        nvs=expand(rules.baseline_frng_nvs.output.record, obj=BASELINE_OBJECTS),
        fits=expand(rules.baseline_fit.output.records, method=PER_SCENE_METHODS, obj=BASELINE_OBJECTS),
        image=expand(rules.baseline_image.output.record, obj=_IMAGE_RUN_IDS),
        external=[e["path"] for e in _BASELINES.get("external", [])],
    output:
        per_image=L.metrics("baselines_per_image"),
        timing=L.metrics("baselines_timing"),
    log:
        L.log("baseline_eval"),
    conda:
        "../envs/eval.yaml"
    threads: 1
    resources:
        mem_mb=4000,
        runtime=30,
    params:
        **stage_params("baseline_eval"),
        out=lambda wildcards, output: os.path.dirname(output.per_image),
    message:
        "Scoring the baselines beside F-RNG"
    shell:
        "exec {params.py:q} -m frng baseline-eval --config {params.config:q} --out {params.out:q} > {log:q} 2>&1"


# rule baseline_tables: Tables 2 and 3 (vs_dense, vs_image_based) and the views table (views_nvs), with figures
BASELINE_TABLES = ("vs_dense", "vs_image_based", "views_nvs")


rule baseline_tables:
    input:
        per_image=rules.baseline_eval.output.per_image,
        timing=rules.baseline_eval.output.timing,
    output:
        tables=[L.table(t, ext) for t in BASELINE_TABLES for ext in ("csv", "md", "tex")],
        figures=[os.path.join(L.figures_dir(), "baselines", f"{t}.png") for t in BASELINE_TABLES],
    log:
        L.log("baseline_tables"),
    conda:
        "../envs/eval.yaml"
    threads: 1
    resources:
        mem_mb=4000,
        runtime=20,
    params:
        **stage_params("baseline_tables"),
        metrics=lambda wildcards, input: os.path.dirname(input.per_image),
    message:
        "Tables 2-3 and the views table"
    shell:
        "exec {params.py:q} -m frng baseline-tables --config {params.config:q} --metrics {params.metrics:q} "
        "> {log:q} 2>&1"


# what rule tables waits for (rules/evaluate.smk: the results page shows these tables when the config has them)
BASELINE_TABLE_FILES = [L.table(t, "md") for t in BASELINE_TABLES] if BASELINE_VIEW_IDS else []
add_targets(*BASELINE_TABLE_FILES)
