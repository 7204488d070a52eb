# Public benchmarks (docs/benchmarks.md); imported ids hold a hyphen, so curate/relight ([a-z0-9_]+) never claim them.
import re as _re

from frng.benchmarks.plan import BenchmarkError as _BenchmarkError
from frng.benchmarks.plan import entries as _benchmark_entries
from frng.benchmarks.plan import import_flags as _import_flags
from frng.plan.variants import model_variants as _model_variants

try:
    BENCHMARKS = {e["id"]: e for e in _benchmark_entries(config)}
    _BENCH_FLAGS = {b: _import_flags(e) for b, e in BENCHMARKS.items()}
except _BenchmarkError as e:
    raise WorkflowError(f"benchmarks: {e}")
BENCH_IDS = list(BENCHMARKS)
_BENCH_RE = "|".join(_re.escape(b) for b in BENCH_IDS) or r"(?!x)x"


rule import_benchmark:
    input:
        folder=lambda wildcards: BENCHMARKS[wildcards.bench]["path"],
    output:
        meta=L.object_meta("{bench}"),
    log:
        L.log("import_benchmark", "{bench}"),
    wildcard_constraints:
        bench=_BENCH_RE,
    conda:
        "../envs/eval.yaml"
    threads: 1
    resources:
        mem_mb=4000,
        runtime=30,
    params:
        **stage_params("import_benchmark"),
        layout=lambda wildcards: BENCHMARKS[wildcards.bench]["layout"],
        flags=lambda wildcards: _BENCH_FLAGS[wildcards.bench],
    message:
        "Importing benchmark scene {wildcards.bench}"
    shell:
        "exec {params.py:q} -m frng import {params.layout:q} {input.folder:q} --config {params.config:q} "
        "--id {wildcards.bench:q} {params.flags} > {log:q} 2>&1"


rule relight_benchmark:
    input:
        models=expand(L.model(), variant=_model_variants(config)),
        backbone=rules.backbone_train.output.model,
        idm=IDM_MODEL,
        meta=rules.import_benchmark.output.meta,
    output:
        timing=L.relight_timing("{bench}"),
    log:
        L.log("relight", "{bench}"),
    wildcard_constraints:
        bench=_BENCH_RE,
    conda:
        "../envs/torch.yaml"
    threads: 2
    resources:
        mem_mb=6000,
        runtime=60,
        gpu=TORCH_GPUS,
    params:
        **stage_params("relight_benchmark"),
        models=lambda wildcards, input: os.path.dirname(os.path.dirname(input.models[0])),
    message:
        "Relighting benchmark object {wildcards.bench}: F-RNG runs and the backbone"
    shell:
        "exec {params.py:q} -m frng relight-benchmark --config {params.config:q} --object {wildcards.bench:q} "
        "--models {params.models:q} "
        "> {log:q} 2>&1"


rule evaluate_benchmarks:
    input:
        timing=expand(rules.relight_benchmark.output.timing, bench=BENCH_IDS),
    output:
        per_image=L.metrics("benchmarks_per_image"),
        tables=[L.table("benchmarks", ext) for ext in ("csv", "md", "tex")],
    log:
        L.log("evaluate_benchmarks"),
    conda:
        "../envs/eval.yaml"
    threads: 1
    resources:
        mem_mb=3000,
        runtime=30,
    params:
        **stage_params("evaluate_benchmarks"),
        objects=BENCH_IDS,
        metrics=lambda wildcards, output: os.path.dirname(output.per_image),
        tables=lambda wildcards, output: os.path.dirname(output.tables[0]),
    message:
        "Scoring {n} benchmark objects with their published protocols".format(n=len(BENCH_IDS))
    shell:
        "exec {params.py:q} -m frng evaluate-benchmarks --config {params.config:q} --objects {params.objects:q} "
        "--metrics {params.metrics:q} --tables {params.tables:q} > {log:q} 2>&1"


if BENCH_IDS:
    add_targets(*rules.evaluate_benchmarks.output)
