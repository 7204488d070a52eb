"""Stage modules are named after their rules (issue 13, item 2), one to one (issue 89): every Snakemake rule that runs
``frng <subcommand>`` runs the module of frng/stages/ named after it, every module of frng/stages/ is run by exactly
one rule; what a user runs by hand lives in frng/commands/, the benchmarks in frng/diagnostics/; ``frng --help``
lists the user's commands before the pipeline's stages, and ``frng <command> --help`` works for each."""

import ast
import importlib
import re
import subprocess
import sys
from pathlib import Path

import pytest

from frng import cli
from frng.diagnostics.bench import BENCHES
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
    "the results folder (frng.plan.curate_jobs.write_curate_record)",
}
# the commands a user runs that no rule runs (frng.commands), and where they are exercised
COMMANDS = {
    "frng.commands.reconstruct": "your own photos -> an asset (tests/test_reconstruct.py)",
    "frng.commands.render_asset": "renders an asset folder (tests/test_reconstruct.py)",
    "frng.commands.export_asset": "bakes an asset into plain 3DGS files, also the viewer's Export button "
    "(tests/test_export.py)",
    "frng.commands.view": "the interactive relighting viewer, frng.apps.view (tests/test_viewer.py)",
    "frng.commands.export_benchmark": "writes curated objects in the public benchmarks' layouts (tests/test_benchmarks.py;"
    " nothing downstream in the workflow reads it)",
    "frng.commands.export_image_inputs": "writes the image-based methods' inputs (tests/test_baselines_tables.py)",
    "frng.commands.config": "validates a config file and prints it, run by make before snakemake",
    "frng.commands.results_page": "regenerates docs/results.md by hand; the rule tables does it through `frng tables "
    "--results-page` (tests/test_results_page.py)",
}
COMMANDS_DIR = ROOT / "frng" / "commands"
DIAGNOSTICS_DIR = ROOT / "frng" / "diagnostics"
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


def test_rules_and_stage_modules_map_one_to_one():
    """Every module of frng/stages/ (but the ``_`` helpers) is run by exactly one rule, and each rule that runs a stage
    runs its own module. Rules that do the same work run thin stages of their own rather than one shared stage:
    ``relight``, ``relight_seed`` and ``relight_benchmark`` each run the stage named after them (whose body is
    frng.stages._relight), as ``backbone_train`` and ``idm_train`` share frng.stages._priors; a stage of its own per
    rule carries the rule's own ``CONFIG_READS`` and so its own config digest (frng.plan.digests), which one shared
    module could not."""
    modules = stage_modules()
    runs: dict[str, list[str]] = {m: [] for m in modules}
    for rule, block in rule_blocks().items():
        sub = frng_subcommand(block)
        if sub is None:
            continue
        module = cli.STAGES[sub][0]
        assert module in runs, f"rule {rule} runs `frng {sub}` ({module}), which is no module of frng/stages/"
        runs[module].append(rule)
    not_one = {m: rules for m, rules in runs.items() if len(rules) != 1}
    assert not not_one, f"stage modules not run by exactly one rule: {not_one}"
    assert sorted(runs) == sorted(RULE_STAGES.values())


def test_commands_and_diagnostics_are_dispatched_and_run_by_no_rule():
    commands = sorted(f"frng.commands.{p.stem}" for p in COMMANDS_DIR.glob("*.py") if p.stem != "__init__")
    assert commands == sorted(COMMANDS)
    assert set(commands) <= {m for m, _ in cli.USER_COMMANDS.values()}
    benches = sorted(f"frng.diagnostics.{p.stem}" for p in DIAGNOSTICS_DIR.glob("bench_*.py"))
    assert benches == sorted(m for m, _ in BENCHES.values())
    assert cli.USER_COMMANDS["bench"][0] == "frng.diagnostics.bench"
    ruled = {cli.STAGES[sub][0] for sub in map(frng_subcommand, rule_blocks().values()) if sub}
    assert not ruled & (set(commands) | set(benches) | {"frng.diagnostics.bench"})


def test_the_subcommand_groups_split_the_subcommands():
    """Every rule's stage is a pipeline stage but ``frng import`` (rule import_benchmark), which a user runs too."""
    assert not set(cli.USER_COMMANDS) & set(cli.PIPELINE_STAGES)
    assert cli.STAGES == {**cli.USER_COMMANDS, **cli.PIPELINE_STAGES}
    in_rules = {frng_subcommand(b) for b in rule_blocks().values()} - {None}
    assert set(cli.PIPELINE_STAGES) == in_rules - {"import"}
    assert all(m.startswith("frng.stages.") for m, _ in cli.PIPELINE_STAGES.values())


def test_every_subcommand_is_a_stage_a_command_or_the_benchmarks():
    for sub, (module, _) in cli.STAGES.items():
        assert (
            module.startswith(("frng.stages.", "frng.commands."))
            or module == "frng.diagnostics.bench"
            or (sub in OUTSIDE_STAGES)
        ), f"`frng {sub}` -> {module}"


def cli_modules() -> list[str]:
    """The stages, the commands and the benchmarks: the modules a subcommand runs."""
    return stage_modules() + sorted(COMMANDS) + sorted(m for m, _ in BENCHES.values())


@pytest.mark.parametrize("module", cli_modules())
def test_stage_module_holds_only_cli_and_orchestration(module):
    """configure(parser) and run(args) at least; no classes (types and algorithms live in the libraries)."""
    tree = ast.parse((ROOT / (module.replace(".", "/") + ".py")).read_text())
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


def test_top_level_help_lists_the_users_commands_first():
    proc = subprocess.run(
        [sys.executable, "-m", "frng", "--help"], cwd=ROOT, capture_output=True, text=True, timeout=60
    )
    assert proc.returncode == 0, proc.stderr
    where = {}
    for sub in cli.STAGES:
        m = re.search(rf"^  {re.escape(sub)}\s", proc.stdout, re.M)
        assert m, sub
        where[sub] = m.start()
    users, stages = proc.stdout.index("commands (what you run):"), proc.stdout.index("pipeline stages")
    assert all(users < where[s] < stages for s in cli.USER_COMMANDS)
    assert all(stages < where[s] for s in cli.PIPELINE_STAGES)
    order = [where[s] for s in cli.PIPELINE_STAGES]
    assert order == sorted(order)


def test_a_diagnostic_geometry_never_overwrites_the_pipelines_model(capsys):
    """`frng train --geometry gbuffer` (the geometry-gap diagnostic) without --out would write
    {results}/models/{variant}: a one-line error instead, before anything is read."""
    with pytest.raises(SystemExit) as e:
        cli.main(["train", "--config", str(ROOT / "config" / "smoke.yaml"), "--geometry", "gbuffer"])
    assert e.value.code == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "--geometry gbuffer needs --out" in err, err
