"""One source of truth per config key (issue 58, item 6): each stage declares once the config sections and keys it
reads (``CONFIG_READS`` of ``frng/stages/<rule>.py``; the bookkeeping rules without a stage in
``frng.plan.digests.STAGELESS_READS``), and the digests (hence the rules' ``params``, Snakemake's rerun trigger), the
digest files and the docs table all derive from that declaration.

Fast: no Snakemake, no stage run (tests/test_config_digests.py runs the workflow's dry runs)."""

import copy
import re
import subprocess
import sys

import pytest
from conftest import ROOT

from frng.plan import config as frng_config
from frng.plan import digests

CONFIG = frng_config.load(ROOT / "config" / "config.yaml")
LEAVES = [k for k in digests.schema_leaves() if k.split(".")[0] not in digests.NOT_DIGESTED]


def edited(config: dict, dotted: str) -> dict:
    """``config`` with the value at ``dotted`` replaced by one that differs from it (whatever its type)."""
    config = copy.deepcopy(config)
    *path, last = dotted.split(".")
    node = config
    for part in path:  # a null mapping (objects.objaverse.filter) becomes one
        node[part] = node.get(part) or {}
        node = node[part]
    node[last] = ["edited", node.get(last)]
    return config


@pytest.mark.parametrize("rule", sorted(digests.RULE_CONFIG_KEYS))
def test_editing_a_declared_key_changes_the_rule_digest_and_no_other_key_does(rule):
    """For every rule with a digest: editing each schema key its declaration covers (a key listed, or a leaf of a
    section listed, not removed by a ``!key``) changes its digest, so its ``params`` rerun it; editing any other
    schema key leaves it unchanged, so nothing else reruns it."""
    base = digests.rule_digest(CONFIG, rule)
    declared = [k for k in LEAVES if digests.reads(rule, k)]
    assert declared, f"rule {rule} declares no schema key"
    stale = [k for k in declared if digests.rule_digest(edited(CONFIG, k), rule) == base]
    needless = [k for k in LEAVES if k not in declared and digests.rule_digest(edited(CONFIG, k), rule) != base]
    assert not stale, f"rule {rule}: declared keys whose edit leaves its digest unchanged: {stale}"
    assert not needless, f"rule {rule}: undeclared keys whose edit changes its digest: {needless}"


@pytest.mark.parametrize("rule", sorted(digests.RULE_CONFIG_KEYS))
def test_every_declared_key_names_a_schema_key(rule):
    """A key listed (or removed) names a key of config/schema.yaml: a misspelt one would digest as null for ever."""
    assert [bad for bad in digests.unknown_digest_keys() if bad.startswith(f"{rule}: ")] == []


# Schema keys no rule reads, and why (frng.plan.digests.NOT_DIGESTED): everything else is declared by some rule.
GLOBAL_KEYS = {
    "results": "where the outputs go, not what they are: a moved or copied results folder reruns nothing",
}


def test_every_schema_key_is_declared_by_some_rule():
    assert {k: v for k, v in digests.NOT_DIGESTED.items() if k in GLOBAL_KEYS} == GLOBAL_KEYS
    assert set(digests.NOT_DIGESTED) - set(GLOBAL_KEYS) == {frng_config.OVERWRITE_SWITCH}  # no schema key
    assert frng_config.OVERWRITE_SWITCH not in frng_config.load_schema()["properties"]
    undeclared = [k for k in digests.schema_leaves() if k.split(".")[0] not in GLOBAL_KEYS]
    undeclared = [k for k in undeclared if not any(digests.reads(rule, k) for rule in digests.RULE_CONFIG_KEYS)]
    assert not undeclared, "; ".join(
        f"config key {k} (config/schema.yaml) is read by no rule: add it (or its section "
        f"{k.split('.')[0]!r}) to CONFIG_READS of frng/stages/<rule>.py of every rule whose stage reads it, or to "
        "frng.plan.digests.NOT_DIGESTED and GLOBAL_KEYS of tests/test_config_reads.py with the reason no rule reads it"
        for k in undeclared
    )


def test_an_undeclared_schema_key_is_refused():
    schema = frng_config.load_schema()
    schema["properties"]["render"]["properties"]["new_leaf"] = {"type": "integer"}  # render.* is declared whole
    schema["properties"]["eval"]["properties"]["new_leaf"] = {"type": "integer"}
    schema["properties"]["new_key"] = {"type": "integer"}
    assert digests.undigested_keys(schema) == ["new_key"]
    schema["properties"]["backbone"]["properties"]["new_leaf"] = {"type": "integer"}
    assert digests.undigested_keys(schema) == ["new_key"]  # backbone.* is declared whole (backbone_train)


def test_declarations_are_read_without_importing_the_stages():
    """The rule files compute the digests while planning: reading the declarations imports no stage and no torch."""
    code = "import sys, frng.plan.digests\nprint(sorted(m for m in sys.modules if m == 'torch' or m.startswith('frng.stages')))"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, cwd=ROOT).stdout
    assert out.strip() == "[]"


def test_the_declaration_is_the_stage_module_constant():
    """RULE_CONFIG_KEYS is the stages' own CONFIG_READS, groups spelled out (what an import of the stage sees)."""
    import importlib

    for rule in ("curate", "train", "relight", "relight_seed", "evaluate"):
        module = importlib.import_module(f"frng.stages.{rule}")
        assert digests.RULE_CONFIG_KEYS[rule] == digests.expand(module.CONFIG_READS), rule
    relight, seeded = digests.RULE_CONFIG_KEYS["relight"], digests.RULE_CONFIG_KEYS["relight_seed"]
    assert "train.seeds" not in relight and set(seeded) - set(relight) == {"train.seeds"}  # `make seeds`
    assert digests.reads("train", "train.steps") and not digests.reads("train", "train.seeds")
    assert not digests.reads("train", "shading.spp_infer") and digests.reads("relight", "shading.spp_infer")


def test_a_bad_declaration_is_one_line_naming_the_file(tmp_path):
    stage = tmp_path / "stage.py"
    stage.write_text("X = 1\nCONFIG_READS = ('train', X)\n")
    with pytest.raises(frng_config.ConfigError, match=r"stage\.py: CONFIG_READS must be a non-empty tuple"):
        digests.stage_declaration(stage)
    stage.write_text("import argparse\n")
    assert digests.stage_declaration(stage) is None
    with pytest.raises(frng_config.ConfigError, match=r"stage\.py: @nope: no such group"):
        digests.expand(("@nope", "train"), "stage.py")
    with pytest.raises(frng_config.ConfigError, match=r"stage\.py: !shading\.spp_infer: removes a key that no"):
        digests.expand(("train", "!shading.spp_infer"), "stage.py")
    assert digests.expand(("@plan", "train", "!train.steps", "!seed")) == (
        *("objects", "envmaps", "render.input_lights", "render.target_lights", "train", "!train.steps"),
    )


DOC = ROOT / "docs" / "provenance-and-reproducibility.md"


def test_the_docs_table_is_the_declarations():
    """docs/provenance-and-reproducibility.md shows what each rule reads as frng.plan.digests.reads_table() writes it."""
    m = re.search(r"<!-- rule-reads:begin[^\n]*-->\n(.*?)<!-- rule-reads:end -->", DOC.read_text(), re.S)
    assert m, f"{DOC}: no <!-- rule-reads:begin --> ... <!-- rule-reads:end --> block"
    assert m.group(1) == digests.reads_table(), (
        f"{DOC}: the rule-reads table differs from the declarations; paste the output of "
        "`python -c 'from frng import digests; print(digests.reads_table(), end=\"\")'`"
    )
