"""What each rule reads: the config digests that rerun it.

Every rule of the workflow declares ``params: config_digest=digests.rule_digest(config, "<rule>")``: a digest of
exactly the config keys its stage reads. Snakemake's ``params`` rerun trigger then reruns a rule whose keys were
edited, and its downstream rules because their inputs are rebuilt; the other rules stay. Digests read the validated
config mapping (no typed sections, no torch: the rule files call this while planning).

Where the keys are declared, once: each stage module ``frng/stages/<rule>.py`` holds ``CONFIG_READS``, a tuple of
string literals beside its entry point (``configure``/``run``), naming the sections and keys its ``run`` reads
(helpers and libraries included). This module reads those tuples from the stages' source (:mod:`ast`, without
importing a stage: stages import torch, planning must not), and :data:`RULE_CONFIG_KEYS`, the digests, the rule
params (``rules/common.smk``: ``stage_params``/``digest_params``), the digest files and the table of
docs/provenance-and-reproducibility.md (:func:`reads_table`) all follow from them. The three bookkeeping rules that
run no stage (their ``run:`` blocks live in ``rules/train.smk``) declare theirs here, :data:`STAGELESS_READS`.
"""

from __future__ import annotations

import ast
import copy
import hashlib
import json
import os
import re
from pathlib import Path
from typing import Any

from frng import io
from frng.plan.config import OVERWRITE_SWITCH
from frng.plan.sections import ConfigError, load_schema

# A key is a dotted path (a whole section or one leaf); ``"!section.key"`` removes a part of a section listed (or a
# key listed, e.g. one a group brings); ``"@group"`` stands for the keys of :data:`GROUPS`. Missing keys digest as
# null. ``results`` and the overwrite switch are never part of a digest (:data:`NOT_DIGESTED`).
#
# A declaration follows what the stage's entry point reads (``config[...]``, ``config.<section>``,
# ``config_section(config, ...)``, helpers and libraries included). A key a stage reads but its declaration lacks
# leaves stale results; a key listed needlessly only costs an extra rerun. Sections an upstream rule already covers
# may be listed whole downstream at no cost (editing them reruns the upstream rule, hence this one). A section listed
# whole covers the keys added to it later: declare by section where the stage reads most of one.

STAGES_DIR = Path(__file__).resolve().parents[1] / "stages"
DECLARATION = "CONFIG_READS"
"""The name of a stage module's declaration: ``CONFIG_READS = ("@plan", "train", "!train.seeds", ...)``."""

PLAN_KEYS: tuple[str, ...] = ("seed", "objects", "envmaps", "render.input_lights", "render.target_lights")
"""What the dataset plan reads (frng/plan/catalog.py ``plan``): env maps and their split, objects, their split,
materials and lights. Every stage that asks the plan for a split or the object list reads these."""

ENVMAP_PLAN_KEYS: tuple[str, ...] = ("seed", "envmaps", "objects", "render.input_lights", "render.target_lights")
"""What the env-map plan reads (frng/plan/catalog.py ``envmap_plan``): one map per (object, light) draw, so the
objects and the light counts too."""

RELIGHT_MODEL_KEYS: tuple[str, ...] = (
    "device",
    "render.resolution",
    "render.extra_input_views",
    "idm",
    "!idm.train",
    "backbone.near",
    "backbone.far",
    "shading",
    "frng",
    "train.seeds",
    "train_seed",
)
"""What relighting one object with the trained models reads (frng/apps/relight.py): the runs (frng.*, idm.kind,
render.extra_input_views, train.seeds), the resolution check, build_idm, shading.spp_infer and the inference
shading, seeds, device."""

GROUPS: dict[str, tuple[str, ...]] = {
    "@plan": PLAN_KEYS,
    "@envmap_plan": ENVMAP_PLAN_KEYS,
    "@relight": RELIGHT_MODEL_KEYS,
}
"""Keys a library entry point that several stages call reads, by the name a declaration uses for them."""

STAGELESS_READS: dict[str, tuple[str, ...]] = {
    # a copy of the full model: which K-sweep entry is the full model
    "model_alias": ("frng.top_k_percent",),
    # indexes of the training split's files (frng.io.write_file_index)
    "training_set_caches": ("@plan",),
    "training_set_priors": ("@plan",),
}
"""The declarations of the rules that run no stage (bookkeeping ``run:``/``shell:`` blocks of rules/train.smk)."""

NOT_DIGESTED: dict[str, str] = {
    "results": "where the outputs go, not what they are: a moved or copied results folder reruns nothing",
    OVERWRITE_SWITCH: "a switch of the run (`--config overwrite_config=true` replaces the recorded config), popped "
    "before validation: no schema key, never recorded",
}
"""Config keys no rule's digest may hold, and why: every other schema key is declared by some rule."""

RULES_WITHOUT_DIGEST = frozenset({"all", "config_digest", "curate_record"})
"""Rules that run no stage (``config_digest`` records the others' digests in the results folder, ``curate_record``
each object's plan entry and maps' records: frng.plan.curate_jobs.curate_record)."""


def stage_declaration(path: str | os.PathLike) -> tuple[str, ...] | None:
    """The ``CONFIG_READS`` of the stage module at ``path``, read from its source without importing it (a module-level
    tuple of string literals); None when it declares none. A declaration that is not such a tuple is a
    :class:`ConfigError` naming the file."""
    path = Path(path)
    found = None
    for node in ast.parse(path.read_text(), str(path)).body:
        targets = (
            node.targets if isinstance(node, ast.Assign) else [node.target] if isinstance(node, ast.AnnAssign) else []
        )
        if any(isinstance(t, ast.Name) and t.id == DECLARATION for t in targets):
            try:
                found = ast.literal_eval(node.value)
            except ValueError:
                found = None
            if not (isinstance(found, tuple) and found and all(isinstance(k, str) for k in found)):
                raise ConfigError(
                    f"{path}: {DECLARATION} must be a non-empty tuple of string literals (dotted config keys)"
                )
    return found


def expand(keys, where: str = "") -> tuple[str, ...]:
    """The keys of a declaration with its groups (``@plan``, :data:`GROUPS`) spelled out, each key once, in order,
    the keys then the removals; a removal ``"!k"`` of a key ``k`` listed as such drops it (and goes: no section
    listed contains it). ``where``: what declares them, for the error on an unknown group."""
    flat: list[str] = []
    for k in keys:
        if k.startswith("@"):
            if k not in GROUPS:
                raise ConfigError(f"{where}: {k}: no such group of config keys; known: {', '.join(GROUPS)}")
            flat += GROUPS[k]
        else:
            flat.append(k)
    listed = [k for k in dict.fromkeys(flat) if not k.startswith("!")]
    removed = list(dict.fromkeys(k[1:] for k in flat if k.startswith("!")))
    include = [k for k in listed if k not in removed]
    for k in removed:
        if k not in listed and not _owned(k, include):
            raise ConfigError(f"{where}: !{k}: removes a key that no key or section listed contains")
    return (*include, *(f"!{k}" for k in removed if _owned(k, include)))


def _within(key: str, section: str) -> bool:
    return key == section or key.startswith(section + ".")


def _owned(key: str, include) -> bool:
    return any(key.startswith(k + ".") for k in include)


def _rule_config_keys() -> dict[str, tuple[str, ...]]:
    out = {}
    for path in sorted(STAGES_DIR.glob("*.py")):
        declared = stage_declaration(path)
        if declared is not None:
            out[path.stem] = expand(declared, str(path.relative_to(STAGES_DIR.parent.parent)))
    for rule, declared in STAGELESS_READS.items():
        if rule in out:
            raise ConfigError(f"rule {rule}: declared by its stage and in frng.plan.digests.STAGELESS_READS")
        out[rule] = expand(declared, f"frng.plan.digests.STAGELESS_READS[{rule!r}]")
    return dict(sorted(out.items()))


RULE_CONFIG_KEYS: dict[str, tuple[str, ...]] = _rule_config_keys()
"""Rule name -> the config keys its stage reads: the stage's ``CONFIG_READS`` (frng/stages/<rule>.py) with its groups
spelled out (:func:`expand`), or :data:`STAGELESS_READS`. Derived: never edit it, edit the declaration."""

_NEVER_DIGESTED = tuple(NOT_DIGESTED)


def reads(rule: str, key: str) -> bool:
    """Whether rule ``rule``'s digest holds the config key ``key`` (a schema leaf): a key or section it lists
    contains it and no removal takes it out."""
    keys = RULE_CONFIG_KEYS[rule]
    return any(_within(key, k) for k in keys if not k.startswith("!")) and not any(
        _within(key, k[1:]) for k in keys if k.startswith("!")
    )


def reads_table() -> str:
    """A Markdown table, rule -> where its keys are declared and the keys (groups by name), for
    docs/provenance-and-reproducibility.md (tests/test_config_reads.py checks that the page holds it)."""
    rows = ["| rule | declared in | config keys it reads (`!`: but not) |", "|---|---|---|"]
    for rule in RULE_CONFIG_KEYS:
        if rule in STAGELESS_READS:
            where, declared = "`frng.plan.digests.STAGELESS_READS`", STAGELESS_READS[rule]
        else:
            where, declared = f"`frng/stages/{rule}.py`", stage_declaration(STAGES_DIR / f"{rule}.py")
        rows.append(f"| `{rule}` | {where} | {', '.join(f'`{k}`' for k in declared)} |")
    rows += ["", "| group | stands for (`frng.plan.digests.GROUPS`) |", "|---|---|"]
    rows += [f"| `{g}` | {', '.join(f'`{k}`' for k in keys)} |" for g, keys in GROUPS.items()]
    return "\n".join(rows) + "\n"


def _declared_where(rule: str) -> str:
    return "frng.plan.digests.STAGELESS_READS" if rule in STAGELESS_READS else f"frng/stages/{rule}.py ({DECLARATION})"


def _undeclared(rule: str) -> str:
    return (
        f"no {DECLARATION} in frng/stages/{rule}.py (the config keys its stage reads; frng.plan.digests.STAGELESS_READS "
        "for a rule that runs no stage)"
    )


def _lookup(config: Any, dotted: str) -> Any:
    node = config
    for part in dotted.split("."):
        if not isinstance(node, dict) or part not in node:
            return None
        node = node[part]
    return node


def config_digest(config: dict, keys, length: int = 16) -> str:
    """A short stable digest (sha256 of canonical JSON, ``length`` hex digits) of the config ``keys``: dotted keys
    or sections, each ``"!key"`` removing a part of a section listed. Key order does not matter; a missing key
    digests as null."""
    keys = list(keys)
    include = sorted({k for k in keys if not k.startswith("!")})
    selected = {k: copy.deepcopy(_lookup(config, k)) for k in include}
    for ex in sorted({k[1:] for k in keys if k.startswith("!")}):
        owners = [k for k in include if ex.startswith(k + ".")]
        if not owners:
            raise ValueError(f"config digest: '!{ex}' removes a key no listed section contains")
        for k in owners:
            node, *rest = selected[k], *ex[len(k) + 1 :].split(".")
            for part in rest[:-1]:
                node = node.get(part) if isinstance(node, dict) else None
            if isinstance(node, dict):
                node.pop(rest[-1], None)
    text = json.dumps(selected, sort_keys=True, separators=(",", ":"), default=str)
    return hashlib.sha256(text.encode()).hexdigest()[:length]


def rule_digest(config: dict, rule: str) -> str:
    """The digest of the config keys rule ``rule`` reads (:data:`RULE_CONFIG_KEYS`): its ``config_digest`` param."""
    if rule not in RULE_CONFIG_KEYS:
        raise ConfigError(f"rule {rule!r}: {_undeclared(rule)}")
    return config_digest(config, RULE_CONFIG_KEYS[rule])


def write_rule_digest(config: dict, rule: str, path: str | os.PathLike, log: str | os.PathLike | None = None) -> Path:
    """Write ``path`` (``{results}/.digests/{rule}-{digest}.txt``, :meth:`frng.plan.layout.Layout.rule_digest`): the keys
    rule ``rule`` reads, their values and digest; and remove the rule's other digest files, so that going back to
    an earlier config finds its file missing again (and reruns the rule). ``log``: where to say so."""
    path = Path(path)
    digest = rule_digest(config, rule)
    if path.name != f"{rule}-{digest}.txt":
        raise ConfigError(f"{path}: not the digest file of rule {rule} for this config ({rule}-{digest}.txt)")
    keys = RULE_CONFIG_KEYS[rule]
    io.write_json(
        path,
        {
            "rule": rule,
            "digest": digest,
            "keys": list(keys),
            "values": {k: _lookup(config, k) for k in keys if not k.startswith("!")},
        },
    )
    for other in path.parent.glob(f"{rule}-*.txt"):
        if other != path and re.fullmatch(rf"{re.escape(rule)}-[0-9a-f]+\.txt", other.name):
            other.unlink(missing_ok=True)
    if log is not None:
        Path(log).parent.mkdir(parents=True, exist_ok=True)
        Path(log).write_text(f"recorded {path}\n")
    return path


def remove_stale_digests(config: dict, folder: str | os.PathLike) -> list[Path]:
    """Remove the digest files ``{folder}/{rule}-{digest}.txt`` of other configs (a run that touched its jobs,
    ``--touch``, leaves them): called when jobs start, never while planning. Returns the files removed."""
    current = {f"{rule}-{rule_digest(config, rule)}.txt" for rule in RULE_CONFIG_KEYS}
    folder = Path(folder)
    removed = []
    if folder.is_dir():
        for f in sorted(folder.iterdir()):
            m = re.fullmatch(r"([a-z][a-z0-9_]*)-[0-9a-f]+\.txt", f.name)
            if m and m.group(1) in RULE_CONFIG_KEYS and f.name not in current:
                f.unlink(missing_ok=True)
                removed.append(f)
    return removed


def check_rule_digests(config: dict, declared: dict[str, Any]) -> None:
    """``declared``: rule name -> its ``config_digest`` param (None when it has none). Raises :class:`ConfigError`
    naming every rule without the right digest, and every map entry naming no rule."""
    problems = []
    for rule, value in sorted(declared.items()):
        if rule in RULES_WITHOUT_DIGEST:
            continue
        if rule not in RULE_CONFIG_KEYS:
            problems.append(f"rule {rule}: {_undeclared(rule)}")
        elif value != rule_digest(config, rule):
            problems.append(
                f'rule {rule}: needs `params: config_digest=frng_digests.rule_digest(config, "{rule}")` (`**digest_params("{rule}")`)'
            )
    problems += [
        f"{_declared_where(r)} declares the config keys of rule {r}: no such rule"
        for r in sorted(set(RULE_CONFIG_KEYS) - set(declared))
    ]
    if problems:
        raise ConfigError("config digests: " + "; ".join(problems))


def _schema_leaves(node: dict, prefix: str = "") -> list[str]:
    out = []
    for name, sub in (node.get("properties") or {}).items():
        if isinstance(sub, dict) and sub.get("properties"):
            out += _schema_leaves(sub, f"{prefix}{name}.")
        else:
            out.append(f"{prefix}{name}")
    return out


def schema_leaves(schema: dict | None = None) -> list[str]:
    """The dotted keys of the schema's leaves (a value that is no section: scalars, lists, plain mappings)."""
    return _schema_leaves(schema if schema is not None else load_schema())


def undigested_keys(schema: dict | None = None) -> list[str]:
    """Config keys of the schema that no rule's digest covers (besides :data:`NOT_DIGESTED`): a key added to the
    schema must be declared (``CONFIG_READS`` of frng/stages/<rule>.py, or a section listed there) by every rule
    whose stage reads it."""
    return [
        leaf
        for leaf in schema_leaves(schema)
        if leaf.split(".")[0] not in _NEVER_DIGESTED and not any(reads(rule, leaf) for rule in RULE_CONFIG_KEYS)
    ]


def unknown_digest_keys(schema: dict | None = None) -> list[str]:
    """Keys of :data:`RULE_CONFIG_KEYS` that name no config key of the schema (a typo would digest as null for
    ever), plus any that must never be digested (``results``, the overwrite switch)."""
    schema = schema if schema is not None else load_schema()
    bad = []
    for rule, keys in RULE_CONFIG_KEYS.items():
        for key in keys:
            node: Any = schema
            for part in key.lstrip("!").split("."):
                node = (node or {}).get("properties", {}).get(part)
            if node is None or key.lstrip("!").split(".")[0] in _NEVER_DIGESTED:
                bad.append(f"{rule}: {key}")
    return bad
