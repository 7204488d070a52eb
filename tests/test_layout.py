"""The results layout is spelled once (frng/plan/layout.py): the rules and the stages ask Layout for every path."""

import re
from pathlib import Path

from frng.plan.layout import Layout

ROOT = Path(__file__).resolve().parents[1]
TOP = (
    "envmaps",
    "objects",
    "previews",
    "backbone",
    "idm",
    "priors",
    "models",
    "relight",
    "metrics",
    "tables",
    "figures",
    "logs",
)


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
    pattern = re.compile(r"""["'](""" + "|".join(TOP) + r""")/""")
    files = [*(ROOT / "rules").glob("*.smk"), ROOT / "workflow" / "Snakefile"]
    _assert_no_match(files, pattern, "results paths")


def test_folders_name_the_files_layout_places():
    """The files inside a folder a stage may be pointed at elsewhere (--out, --envmaps, staging folders) are named by
    the folder classes, and Layout asks them: one spelling of each name."""
    from frng.plan.layout import EnvmapFolder, ObjectFolder, RelightFolder, TrainingFolder

    L = Layout("res")
    assert EnvmapFolder("stage").index() == "stage/index.json" and L.envmap_index() == "res/envmaps/index.json"
    assert (
        EnvmapFolder("stage").envmap("sky") == "stage/sky.exr"
        and EnvmapFolder("stage").record("sky") == "stage/sky.json"
    )
    assert EnvmapFolder(".").envmap("sky") == "sky.exr" and Layout(".").envmap("sky") == "envmaps/sky.exr"
    assert ObjectFolder("t").image("inputs", "l0", "in_00") == "t/inputs/l0/in_00.exr"
    assert L.object_gbuffer("obj_0001", "in_00") == "res/objects/obj_0001/gbuffer/in_00.exr"
    assert TrainingFolder("o").checkpoint() == "o/checkpoint.pt" and TrainingFolder("o").summary() == "o/train.json"
    assert L.backbone_model() == TrainingFolder(L.backbone_dir()).model() == "res/backbone/model.pt"
    assert L.idm_curve("png") == "res/idm/loss.png" and L.model("k4") == "res/models/k4/model.pt"
    assert L.relight_saliency("full", "obj_0001") == "res/relight/full/obj_0001/saliency.npz"
    assert RelightFolder("s/full").image("l0", "tgt_000") == "s/full/l0/tgt_000.exr"
    assert RelightFolder("s/full").record() == "s/full/run.json" and RelightFolder("s").asset() == "s/asset"


def test_library_spells_no_file_names():
    """No module of frng/ but frng/plan/layout.py quotes a results file name ("meta.json", "model.pt", ...)."""
    pattern = re.compile(
        r"""["'](meta|index|run|train)\.json["']|["'](model|checkpoint)\.pt["']|["']loss\.(csv|png)["']"""
        r"""|["']saliency\.npz["']"""
    )
    _assert_no_match([f for f in (ROOT / "frng").rglob("*.py") if f.name != "layout.py"], pattern, "results file names")


def _assert_no_match(files: list[Path], pattern: re.Pattern, what: str) -> None:
    offenders = [
        f"{f.relative_to(ROOT)}:{i}: {line.strip()}"
        for f in files
        for i, line in enumerate(f.read_text().splitlines(), 1)
        if pattern.search(line)
    ]
    assert not offenders, f"{what} spelled outside frng/plan/layout.py:\n" + "\n".join(offenders)
