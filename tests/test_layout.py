"""The results layout is spelled once (frng/layout.py): the rules and the stages ask Layout for every path."""

import re
from pathlib import Path

from frng.layout import Layout

ROOT = Path(__file__).resolve().parents[1]
TOP = ("envmaps", "objects", "previews", "backbone", "idm", "priors", "models", "relight", "metrics", "tables",
       "figures", "logs")


def test_paths_and_wildcards():
    L = Layout("res")
    assert L.object_meta() == "res/objects/{obj}/meta.json"
    assert L.object_meta("obj_0001") == "res/objects/obj_0001/meta.json"
    assert L.model() == "res/models/{variant}/model.pt" and L.model_curve("k4", "png") == "res/models/k4/loss.png"
    assert L.relight_record("{run}", "{{obj}}") == "res/relight/{run}/{{obj}}/run.json"
    assert L.log("curate", "{obj}") == "res/logs/curate/{obj}.log" and L.log("tables") == "res/logs/tables.log"
    assert L.metrics("idm") == "res/metrics/idm.csv" and L.table("views", "tex") == "res/tables/views.tex"


def test_rule_files_spell_no_results_paths():
    """No rule file joins a results sub-folder by hand: a quoted string starting with a top-level folder of the
    layout (e.g. "objects/{obj}/meta.json") would be a second spelling of it."""
    pattern = re.compile(r"""["'](%s)/""" % "|".join(TOP))
    files = [*(ROOT / "rules").glob("*.smk"), ROOT / "workflow" / "Snakefile"]
    offenders = [f"{f.name}:{i}: {line.strip()}" for f in files
                 for i, line in enumerate(f.read_text().splitlines(), 1) if pattern.search(line)]
    assert not offenders, "results paths spelled outside frng/layout.py:\n" + "\n".join(offenders)
