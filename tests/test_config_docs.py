"""config/README.md's key tables and config/schema.yaml name the same keys (issue 26 item 3). Both are generated from
the keys the section dataclasses declare (frng.plan.sections.key; tests/test_config_declared.py checks they are what
``make config-docs`` writes); this checks the README's tables still list every key the schema has, and no other.

A table row names config keys when its first cell starts with a backticked key whose first part is a top-level
key of the schema: ``| `backbone.width` / `heads` |`` names backbone.width and backbone.heads (siblings);
``frng.saliency.*`` and a whole section (``objects.material_mix``) name every key under them. Other rows (files,
list items' fields) are no keys.
"""

from __future__ import annotations

import re
from pathlib import Path

from frng.plan.sections import load_schema

ROOT = Path(__file__).resolve().parents[1]


def schema_keys(node: dict, prefix: str = "") -> dict[str, bool]:
    """dotted key -> whether it is a leaf, over every key of the schema (sections included)."""
    out = {}
    for name, sub in (node.get("properties") or {}).items():
        key = f"{prefix}{name}"
        nested = isinstance(sub, dict) and bool(sub.get("properties"))
        out[key] = not nested
        if nested:
            out.update(schema_keys(sub, key + "."))
    return out


def readme_keys(text: str, top: set[str]) -> set[str]:
    """The dotted keys (or ``section.*``) the README's table rows name."""
    out = set()
    for cell in re.findall(r"^\| (`[^|]+?) \|", text, re.M):
        names = re.findall(r"`([^`]+)`", cell)
        if not names or names[0].split(".")[0] not in top:
            continue
        first = names[0]
        out.add(first)
        parent = first.rpartition(".")[0]
        out.update(f"{parent}.{n}" if parent else n for n in names[1:])
    return out


def test_readme_table_lists_every_schema_key_and_no_other():
    keys = schema_keys(load_schema())
    leaves = {k for k, leaf in keys.items() if leaf}
    top = {k for k in keys if "." not in k}
    named = readme_keys((ROOT / "config" / "README.md").read_text(), top)
    unknown = sorted(n for n in named if n.removesuffix(".*") not in keys)
    covered = {
        leaf
        for leaf in leaves
        for n in named
        if leaf == n.removesuffix(".*") or leaf.startswith(n.removesuffix(".*") + ".")
    }
    assert not unknown, f"config/README.md names keys config/schema.yaml does not have: {unknown}"
    missing = sorted(leaves - covered)
    assert not missing, f"config/schema.yaml keys missing from config/README.md's tables: {missing}"
