"""`frng envmaps` is all-or-nothing: a failed run leaves no record ``{name}.json`` without its map ``{name}.exr``,
also after Snakemake deletes the failed job's declared outputs (the maps and the index), and records orphaned by
earlier runs are removed. Uses users' maps only (no sky bakes), so it runs in about a second."""

import numpy as np
from data_helpers import frng, write_config

from frng.render import envmap


def _maps(tmp_path, bad: bool):
    folder = tmp_path / "maps"
    folder.mkdir(exist_ok=True)
    rng = np.random.default_rng(0)
    for name in ("a_good", "b_good"):
        envmap.write(folder / f"{name}.exr", rng.uniform(0.1, 1.0, (16, 32, 3)).astype(np.float32))
    extra = [
        {"path": str(folder / "a_good.exr"), "split": "train"},
        {"path": str(folder / "b_good.exr"), "split": "test"},
    ]
    if bad:
        (folder / "c_bad.exr").write_bytes(b"not an exr at all")
        extra.append({"path": str(folder / "c_bad.exr"), "split": "train"})
    return extra


def _config(tmp_path, bad: bool):
    return write_config(
        tmp_path / "c.yaml",
        tmp_path / "results",
        envmaps={"bundled": [], "skies": {"models": []}, "extra": _maps(tmp_path, bad), "width": 16},
    )


def _orphans(out):
    return sorted(p.name for p in out.glob("*.json") if p.name != "index.json" and not p.with_suffix(".exr").exists())


def test_failed_envmaps_leave_no_record_without_its_map(tmp_path):
    cfg = _config(tmp_path, bad=True)
    out = tmp_path / "results" / "envmaps"
    proc = frng("envmaps", "--config", str(cfg), check=False)
    assert proc.returncode != 0 and "c_bad.exr" in proc.stderr, proc.stderr
    assert _orphans(out) == []
    # Snakemake deletes the declared outputs of a failed job: the maps and the index, not the records
    for p in list(out.glob("*.exr")) + list(out.glob("index.json")):
        p.unlink()
    assert _orphans(out) == [], "records of the maps written before the failure are left without their maps"
    assert not list(out.glob(".tmp-*")), "staging folder left behind"


def test_orphaned_records_and_staging_folders_are_removed(tmp_path):
    cfg = _config(tmp_path, bad=False)
    out = tmp_path / "results" / "envmaps"
    out.mkdir(parents=True)
    (out / "gone_r0.json").write_text("{}\n")  # its map was deleted (e.g. by Snakemake after a failure)
    (out / ".tmp-envmaps-abcd1234").mkdir()  # staging folder of a killed run
    (out / ".tmp-envmaps-abcd1234" / "x.exr").write_bytes(b"partial")
    frng("envmaps", "--config", str(cfg))
    assert not (out / "gone_r0.json").exists() and not (out / ".tmp-envmaps-abcd1234").exists()
    assert _orphans(out) == []
    # one map per (object, light) draw: the train object's (obj_0001) of a_good, the test object's of b_good
    assert sorted(p.name for p in out.glob("*.exr")) == ["user_a_good_r0-obj_0001.exr", "user_b_good_r0-obj_0000.exr"]
    assert (out / "user_a_good_r0-obj_0001.json").exists() and (out / "index.json").exists()
