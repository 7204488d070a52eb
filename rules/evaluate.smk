# Evaluation, the paper's tables and figures (frng/stages/{evaluate,tables,figures}.py), also for `snakemake --report`.
import shlex

from frng.report.tables import TABLE_COLUMNS

TABLE_NAMES = list(TABLE_COLUMNS)  # the paper's five tables + the ladder and its per-class part (frng/report/tables.py)
_TABLE_CAPTIONS = {
    "vs_backbone": "F-RNG vs backbone",
    "ablation": "ablation",
    "additions": "the project's additions",
    "views": "number of input views",
    "k": "top-K patches",
    "timing": "timing",
    "ladder": "quality ladder",
    "lambertian": "Lambertian base per material class",
    "vs_backbone_by_light": "F-RNG vs backbone per light family",
    "vs_backbone_by_source": "F-RNG vs backbone per object source",
    "ablation_by_light": "ablation per light family",
    "ladder_by_light": "quality ladder per light family",
    "ladder_by_class": "quality ladder per material class",
    "claims": "the paper's claims",
}
# The default tier's tables also rewrite the results page and README block, so that `make reproduce` refreshes them.
RESULTS_PAGE_ARGS = (
    f"--results-page {shlex.quote(str(ROOT / 'docs' / 'results.md'))} --readme {shlex.quote(str(ROOT / 'README.md'))}"
    if config.get("tier") == "default"
    else ""
)


rule evaluate:
    input:
        # one timing file per test object stands for all its runs (relight writes it last): a small paper DAG
        timing=expand(rules.relight.output.timing, obj=TEST_IDS),
        seeded=expand(rules.relight_seed.output.runs, obj=TEST_IDS, seed=RELIGHT_SEEDS),
    output:
        per_image=L.metrics("relight_per_image"),
        summary=L.metrics("relight_summary"),
        cross=L.metrics("relight_cross_light"),
    log:
        L.log("evaluate"),
    conda:
        "../envs/eval.yaml"
    threads: 1
    resources:
        mem_mb=3000,
        runtime=30,
    params:
        **stage_params("evaluate"),
        out=lambda wildcards, output: os.path.dirname(output.per_image),
        objects=TEST_IDS,
    message:
        "Per-image relighting metrics ({protocol} protocol) of {n} test objects".format(
            protocol=config["eval"]["protocol"], n=len(TEST_IDS)
        )
    shell:
        "exec {params.py:q} -m frng evaluate --config {params.config:q} --objects {params.objects:q} --out {params.out:q} > {log:q} 2>&1"


rule tables:
    input:
        per_image=rules.evaluate.output.per_image,
        cross=rules.evaluate.output.cross,
        timing=expand(rules.relight.output.timing, obj=TEST_IDS),
        prior=rules.eval_backbone.output.backbone,
        noise=NOISE_FLOOR,  # the ladder's step 0 (rules/curate.smk), when the config asks for it
        # what the results page shows (default tier only: other tiers make tables and figures side by side)
        ablation_figure=L.figure("ablation.png") if RESULTS_PAGE_ARGS else [],
        real_figure=L.figure("real_objects.png") if RESULTS_PAGE_ARGS and REAL_TEST_IDS else [],
        # Tables 2-3 and the views table, when the config runs the baselines
        baselines=lambda wildcards: BASELINE_TABLE_FILES if RESULTS_PAGE_ARGS else [],
    output:
        *[
            report(
                L.table(t),
                caption=f"../workflow/report/{t}.rst",
                category="Tables",
                labels={"table": _TABLE_CAPTIONS[t]},
            )
            for t in TABLE_NAMES
        ],
        *[L.table(t, ext) for t in TABLE_NAMES for ext in ("md", "tex")],
    log:
        L.log("tables"),
    conda:
        "../envs/eval.yaml"
    threads: 1
    resources:
        mem_mb=2000,
        runtime=10,
    params:
        **stage_params("tables"),
        out=lambda wildcards, output: os.path.dirname(output[0]),
        page=RESULTS_PAGE_ARGS,
        noise=" ".join(f"--noise-floor {shlex.quote(f)}" for f in NOISE_FLOOR),
    message:
        "The paper's tables: {names}".format(names=", ".join(TABLE_NAMES))
    shell:
        "exec {params.py:q} -m frng tables --config {params.config:q} --metrics {input.per_image:q} --timing {input.timing:q} "
        "--prior-metrics {input.prior:q} --cross-light {input.cross:q} {params.noise} --out {params.out:q} {params.page} "
        "> {log:q} 2>&1"


rule figures:
    input:
        per_image=rules.evaluate.output.per_image,
        timing=expand(rules.relight.output.timing, obj=TEST_IDS),
        curves=expand(L.model_curve(), variant=FRNG_VARIANTS),
    output:
        comparison=report(
            directory(L.figure("comparison")),
            patterns=["{obj}.png"],
            caption="../workflow/report/comparison.rst",
            category="Figures",
            subcategory="Relighting",
            labels={"object": "{obj}"},
        ),
        saliency=report(
            directory(L.figure("saliency")),
            patterns=["{obj}.png"],
            caption="../workflow/report/saliency.rst",
            category="Figures",
            subcategory="Saliency",
            labels={"object": "{obj}"},
        ),
        ablation=report(
            L.figure("ablation.png"),
            caption="../workflow/report/ablation_grid.rst",
            category="Figures",
            subcategory="Ablations",
            labels={"figure": "ablation grid"},
        ),
        # the ablation grid of the real assets among the test objects (the README's picture), when there are any
        real=(
            report(
                L.figure("real_objects.png"),
                caption="../workflow/report/real_objects.rst",
                category="Figures",
                subcategory="Ablations",
                labels={"figure": "real objects"},
            )
            if REAL_TEST_IDS
            else []
        ),
        curves=report(
            L.figure("loss_curves.png"),
            caption="../workflow/report/loss_curves.rst",
            category="Figures",
            subcategory="Training",
            labels={"figure": "loss curves"},
        ),
    log:
        L.log("figures"),
    conda:
        "../envs/eval.yaml"
    threads: 1
    resources:
        mem_mb=2000,
        runtime=10,
    params:
        **stage_params("figures"),
        out=lambda wildcards, output: os.path.dirname(output.ablation),
        objects=TEST_IDS,
    message:
        "Figures: comparison grids, ablation grids, saliency maps, loss curves"
    shell:
        "exec {params.py:q} -m frng figures --config {params.config:q} --objects {params.objects:q} --out {params.out:q} > {log:q} 2>&1"


add_targets(
    *[L.table(t, ext) for t in TABLE_NAMES for ext in ("csv", "md", "tex")],
    L.figure("ablation.png"),
    *([L.figure("real_objects.png")] if REAL_TEST_IDS else []),
    L.figure("loss_curves.png"),
    L.figure("comparison"),
    L.figure("saliency"),
)
