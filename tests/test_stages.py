"""Stage modules are named after their rules (issue 13, item 2): every Snakemake rule's stage exists and is what the
rule's ``frng <subcommand>`` runs, every module of frng/stages/ has a rule (or is a documented exception), and
``frng <stage> --help`` works for each."""

import ast
import importlib
import re
import subprocess
import sys
from pathlib import Path

import pytest

from frng import cli
from frng.plan.variants import torchrun_command

ROOT = Path(__file__).resolve().parents[1]
STAGES_DIR = ROOT / "frng" / "stages"

# rule -> the stage module its shell command runs (``frng <subcommand>``, :data:`frng.cli.STAGES`)
RULE_STAGES = {
    "envmaps": "frng.stages.envmaps",
    "curate": "frng.stages.curate",
    "noise_floor": "frng.stages.noise_floor",
    "dataset_preview": "frng.stages.dataset_preview",
    "backbone_train": "frng.stages.backbone_train",
    "idm_train": "frng.stages.idm_train",
    "backbone_cache": "frng.stages.backbone_cache",
    "idm_priors": "frng.stages.idm_priors",
    "eval_backbone": "frng.stages.eval_backbone",
    "train": "frng.stages.train",
    "relight": "frng.stages.relight",
    "relight_seed": "frng.stages.relight_seed",
    "evaluate": "frng.stages.evaluate",
    "tables": "frng.stages.tables",
    "figures": "frng.stages.figures",
    "import_benchmark": "frng.stages.import_benchmark",
    "relight_benchmark": "frng.stages.relight_benchmark",
    "evaluate_benchmarks": "frng.stages.evaluate_benchmarks",
    "curate_baselines": "frng.stages.curate_baselines",
    "baseline_fit": "frng.stages.baseline_fit",
    "baseline_image": "frng.stages.baseline_image",
    "baseline_frng_nvs": "frng.stages.baseline_frng_nvs",
    "baseline_eval": "frng.stages.baseline_eval",
    "baseline_tables": "frng.stages.baseline_tables",
}
# rules that run no ``frng`` stage, and why
NO_STAGE = {
    "model_alias": "Snakemake bookkeeping: `cp` of the full model into the K-sweep entry that equals it",
    "training_set_caches": "Snakemake bookkeeping: a `run:` block writing an index of the training split's files "
    "(frng.io.write_file_index)",
    "training_set_priors": "Snakemake bookkeeping: likewise, the index of the training split's IDM priors",
    "config_digest": "Snakemake bookkeeping: a `run:` block recording a rule's config digest in the results folder "
    "(frng.plan.digests.write_rule_digest)",
    "curate_record": "Snakemake bookkeeping: a `run:` block recording an object's plan entry and maps' records in "
    "the results folder (frng.plan.catalog.write_curate_record)",
}
# stage modules without a rule, and why
STAGES_WITHOUT_RULE = {
    "frng.stages.bench": "benchmarks are run by hand (`make bench`), never by the workflow",
    "frng.stages.bench_render": "`frng bench render` (frng.stages.bench.BENCHES), run by hand",
    "frng.stages.bench_relight": "`frng bench relight` (frng.stages.bench.BENCHES), run by hand",
    "frng.stages.bench_perceptual": "`frng bench perceptual` (frng.stages.bench.BENCHES), run by hand",
    "frng.stages.bench_cues": "`frng bench cues` (frng.stages.bench.BENCHES), run by hand",
    "frng.stages.bench_heldout": "`frng bench heldout` (frng.stages.bench.BENCHES), run by hand on a finished run",
    "frng.stages.bench_backbone": "`frng bench backbone` (frng.stages.bench.BENCHES), run by hand on a finished run",
    "frng.stages.bench_train": "`frng bench train` (frng.stages.bench.BENCHES), run by hand on a finished run",
    "frng.stages.bench_targets_noise": "`frng bench targets-noise` (frng.stages.bench.BENCHES), run by hand (the "
    "curated images' noise floor; tests/test_clean_targets.py)",
    "frng.stages.export_benchmark": "writes curated objects in the public benchmarks' layouts, run by hand and by "
    "tests/test_benchmarks.py (nothing downstream in the workflow reads it)",
    "frng.stages.reconstruct": "your own photos -> an asset, run by hand (tests/test_reconstruct.py)",
    "frng.stages.render_asset": "renders an asset folder, run by hand (tests/test_reconstruct.py)",
    "frng.stages.export_asset": "bakes an asset into plain 3DGS files, run by hand and by the viewer's Export button "
    "(tests/test_export.py)",
    "frng.stages.view": "the interactive relighting viewer (frng.apps.view), run by hand (tests/test_viewer.py)",
    "frng.stages.export_image_inputs": "writes the image-based methods' inputs (one photo + target maps), run by hand "
    "(tests/test_baselines_tables.py)",
    "frng.stages.config": "`frng config` validates a config file and prints it, run by make before snakemake",
    "frng.stages.results_page": "regenerates docs/results.md by hand; the rule tables does it through `frng tables "
    "--results-page` (tests/test_results_page.py)",
}
# ``frng`` subcommands whose module is not in frng/stages/, and why
OUTSIDE_STAGES: dict[str, str] = {}
# ``frng <subcommand> <action>`` of the rules' commands (a stage with sub-subcommands)
SUB_ACTIONS = {"bench": ["render", "relight", "perceptual"]}
# rules whose ``frng`` subcommand is not the rule's name with dashes
CLI_NAMES_DIFFER = {"import_benchmark": "import"}


def rule_blocks() -> dict[str, str]:
    """rule name -> its text, over rules/*.smk. Rules generated in a loop (`rule:` + `name: f"backbone_cache_{_batch}"`,
    rules/priors.smk) count under their family's name."""
    blocks = {}
    for f in sorted((ROOT / "rules").glob("*.smk")):
        parts = re.split(r'^(?:rule (\w+):|\s+rule:\n\s+name:\n\s+f"(\w+)_\{\w+\}")\s*$', f.read_text(), flags=re.M)
        for name, family, body in zip(parts[1::3], parts[2::3], parts[3::3]):
            name = name or family
            assert name not in blocks, f"rule {name} defined twice"
            blocks[name] = body
    return blocks


def shell_of(block: str) -> str:
    """A rule's shell command ("" for a ``run:`` rule)."""
    return block.split("shell:", 1)[1] if "shell:" in block else ""


def frng_subcommand(block: str) -> str | None:
    """The ``frng`` subcommand a rule's shell command runs: ``{params.py} -m frng SUB`` or, for the training rule,
    ``{params.launcher} SUB`` (the launcher ends in ``-m frng``, checked below); an older spelling
    (:data:`frng.cli.ALIASES`) as the stage it names."""
    m = re.search(r"-m frng ([\w-]+)( [\w-]+)?|\{params\.launcher\} ([\w-]+)", shell_of(block))
    if not m:
        return None
    words = [m.group(1), (m.group(2) or "").strip()] if m.group(1) else [m.group(3)]
    return cli.canonical([w for w in words if w])[0]


def stage_modules() -> list[str]:
    return sorted(f"frng.stages.{p.stem}" for p in STAGES_DIR.glob("*.py") if not p.stem.startswith("_"))


def test_every_rule_is_mapped_once():
    rules = set(rule_blocks())
    assert not set(RULE_STAGES) & set(NO_STAGE)
    assert rules == set(RULE_STAGES) | set(NO_STAGE), (
        f"rules without an entry here: {sorted(rules - set(RULE_STAGES) - set(NO_STAGE))}; "
        f"entries without a rule: {sorted((set(RULE_STAGES) | set(NO_STAGE)) - rules)}"
    )


@pytest.mark.parametrize("rule", sorted(RULE_STAGES))
def test_rule_runs_the_stage_named_after_it(rule):
    module = RULE_STAGES[rule]
    assert module == f"frng.stages.{rule}" and (STAGES_DIR / f"{rule}.py").is_file()
    sub = frng_subcommand(rule_blocks()[rule])
    assert sub in cli.STAGES, f"rule {rule} runs `frng {sub}`, which is no stage"
    assert cli.STAGES[sub][0] == module, f"`frng {sub}` (rule {rule}) dispatches to {cli.STAGES[sub][0]}"
    assert sub == CLI_NAMES_DIFFER.get(rule, rule.replace("_", "-")), f"rule {rule} runs `frng {sub}`"


@pytest.mark.parametrize("rule", sorted(NO_STAGE))
def test_bookkeeping_rules_run_no_stage(rule):
    block = rule_blocks()[rule]
    assert frng_subcommand(block) is None and "frng" not in shell_of(block)


def test_training_launcher_runs_the_frng_cli():
    assert torchrun_command(1, python="py") == "py -m frng"
    assert torchrun_command(2, python="py").endswith(" -m frng")


def test_every_stage_has_a_rule_and_a_subcommand():
    modules = stage_modules()
    ruled, exempt = set(RULE_STAGES.values()), set(STAGES_WITHOUT_RULE)
    assert not ruled & exempt
    assert set(modules) == ruled | exempt, (
        f"stages without a rule: {sorted(set(modules) - ruled - exempt)}; "
        f"missing stage modules: {sorted(ruled | exempt - set(modules))}"
    )
    from frng.stages.bench import BENCHES

    dispatched = {m for m, _ in cli.STAGES.values()} | {m for m, _ in BENCHES.values()}
    assert set(modules) <= dispatched, f"stages no subcommand runs: {sorted(set(modules) - dispatched)}"


def test_every_subcommand_is_a_stage_module():
    for sub, (module, _) in cli.STAGES.items():
        assert module.startswith("frng.stages.") or sub in OUTSIDE_STAGES, f"`frng {sub}` -> {module}"


@pytest.mark.parametrize("module", stage_modules())
def test_stage_module_holds_only_cli_and_orchestration(module):
    """configure(parser) and run(args) at least; no classes (types and algorithms live in the libraries)."""
    tree = ast.parse((STAGES_DIR / f"{module.rsplit('.', 1)[1]}.py").read_text())
    functions = {n.name for n in tree.body if isinstance(n, ast.FunctionDef)}
    classes = [n.name for n in tree.body if isinstance(n, ast.ClassDef)]
    assert {"configure", "run"} <= functions and not classes, (module, sorted(functions), classes)
    mod = importlib.import_module(module)
    assert callable(mod.configure) and callable(mod.run)


@pytest.mark.parametrize(
    "argv",
    [[sub] for sub in cli.STAGES] + [[sub, action] for sub, actions in SUB_ACTIONS.items() for action in actions],
)
def test_stage_help(argv, capsys):
    with pytest.raises(SystemExit) as e:
        cli.main([*argv, "--help"])
    assert e.value.code == 0
    out = capsys.readouterr().out
    assert out.startswith(f"usage: frng {' '.join(argv)}"), out[:200]


def test_older_spelling_runs_the_same_stage(capsys):
    """``frng dataset preview`` (what rules/curate.smk runs) is ``frng dataset-preview``."""
    assert cli.canonical(["dataset", "preview", "--cell", "64"]) == ["dataset-preview", "--cell", "64"]
    for old, name in cli.ALIASES.items():
        assert name in cli.STAGES and old[0] not in cli.STAGES
        with pytest.raises(SystemExit) as e:
            cli.main([*old, "--help"])
        assert e.value.code == 0
        assert capsys.readouterr().out.startswith(f"usage: frng {name}")


def test_top_level_help_lists_every_stage():
    proc = subprocess.run(
        [sys.executable, "-m", "frng", "--help"], cwd=ROOT, capture_output=True, text=True, timeout=60
    )
    assert proc.returncode == 0, proc.stderr
    for sub in cli.STAGES:
        assert re.search(rf"^  {re.escape(sub)}\s", proc.stdout, re.M), sub


def test_a_diagnostic_geometry_never_overwrites_the_pipelines_model(capsys):
    """`frng train --geometry gbuffer` (the geometry-gap diagnostic) without --out would write
    {results}/models/{variant}: a one-line error instead, before anything is read."""
    with pytest.raises(SystemExit) as e:
        cli.main(["train", "--config", str(ROOT / "config" / "smoke.yaml"), "--geometry", "gbuffer"])
    assert e.value.code == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "--geometry gbuffer needs --out" in err, err
