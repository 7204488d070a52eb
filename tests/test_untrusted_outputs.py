"""Outputs never destroy (issue 56, docs/reliability.md): a non-empty ``--out`` that is not a previous output of the
same command is refused (``--force`` replaces only what the command writes); every multi-file output is built in a
staging folder and swapped in, so a failure -- a full disk, simulated by an ``OSError(ENOSPC)`` from the EXR writer --
leaves the previous result whole and names the file.

Cases: ``frng reconstruct --out`` of a folder holding notes (probe 2), a re-import on a full disk (probe 5: the previous
import's lights stay), ``render-asset`` on a full disk (no ``turn_000.exr`` left behind), ``export`` into a foreign
folder, and the staging helper itself (frng.confine.staged_output).
"""

from __future__ import annotations

import errno
import hashlib
import json
import os

import numpy as np
import pytest
import torch
from data_helpers import write_config
from test_benchmarks import RES, make_curated
from test_untrusted_confinement import snapshot

from frng import cli, confine
from frng.benchmarks import export_object, import_scene
from frng.render import envmap


def _run(argv, capsys) -> tuple[int, list[str]]:
    """``frng ARGV`` in this process: (exit code, non-empty output lines)."""
    with pytest.raises(SystemExit) as ex:
        cli.main([str(a) for a in argv])
    out = capsys.readouterr()
    return ex.value.code, [ln for ln in (out.out + out.err).splitlines() if ln.strip()]


class FullDisk:
    """Replaces ``OpenEXR.File`` so that every write after the first ``allow`` fails as on a full disk."""

    def __init__(self, monkeypatch, allow: int):
        import OpenEXR

        real, state = OpenEXR.File, {"writes": 0}
        self.state = state

        class File:
            def __init__(self, *a, **k):
                self._f = real(*a, **k)

            def __enter__(self):
                self._f.__enter__()
                return self

            def __exit__(self, *a):
                return self._f.__exit__(*a)

            def write(self, path):
                state["writes"] += 1
                if state["writes"] > allow:
                    raise OSError(errno.ENOSPC, "No space left on device")
                return self._f.write(path)

            def __getattr__(self, name):
                return getattr(self._f, name)

        monkeypatch.setattr(OpenEXR, "File", File)


# -- probe 2: reconstruct --out DIR wiped DIR --------------------------------------------------------------------


def test_reconstruct_refuses_a_folder_it_did_not_write(tmp_path, capsys):
    out = tmp_path / "mine"
    (out / "sub").mkdir(parents=True)
    (out / "notes.txt").write_text("my notes\n")
    (out / "sub" / "keep.txt").write_text("keep\n")
    before = snapshot(out)
    (tmp_path / "photos").mkdir()
    cfg = write_config(tmp_path / "c.yaml", tmp_path / "results")
    code, lines = _run(["reconstruct", "--images", tmp_path / "photos", "--out", out, "--config", cfg], capsys)
    assert code == 2 and len(lines) == 1, lines
    assert str(out) in lines[0] and "--force" in lines[0] and "not a previous output" in lines[0], lines
    assert snapshot(out) == before


# -- the staging helper -------------------------------------------------------------------------------------------


def test_staged_output_rules(tmp_path):
    out = tmp_path / "out"
    with confine.staged_output(out, "render-asset") as stage:
        (stage / "a.exr").write_text("1")
        (stage / "b.exr").write_text("1")
    m = confine.read_manifest(out)
    assert m["command"] == "render-asset" and m["hashed"] and sorted(m["files"]) == ["a.exr", "b.exr"]
    assert m["files"]["a.exr"] == hashlib.sha256(b"1").hexdigest()
    (out / "mine.txt").write_text("the user's")
    # a rerun of the same command: its stale file goes, the user's file stays
    with confine.staged_output(out, "render-asset") as stage:
        (stage / "a.exr").write_text("2")
    assert sorted(p.name for p in out.iterdir()) == [confine.MANIFEST, "a.exr", "mine.txt"]
    assert (out / "a.exr").read_text() == "2"
    # a failure inside leaves the previous output whole and no staging folder behind
    before = snapshot(tmp_path)
    with pytest.raises(OSError):
        with confine.staged_output(out, "render-asset") as stage:
            (stage / "a.exr").write_text("3")
            raise OSError(errno.ENOSPC, "No space left on device")
    assert snapshot(tmp_path) == before
    # another command's output, and a foreign folder, are refused; --force keeps what the command does not write
    with pytest.raises(confine.OutputError, match=r"a previous output of `frng render-asset`"):
        with confine.staged_output(out, "reconstruct"):
            pass
    foreign = tmp_path / "foreign"
    (foreign / "deep").mkdir(parents=True)
    (foreign / "deep" / "x.txt").write_text("x")
    (foreign / "a.exr").write_text("theirs")
    with pytest.raises(confine.OutputError, match=r"foreign: --out is not empty"):
        with confine.staged_output(foreign, "render-asset"):
            pass
    assert (foreign / "a.exr").read_text() == "theirs"
    with confine.staged_output(foreign, "render-asset", force=True) as stage:
        (stage / "a.exr").write_text("ours")
    assert (foreign / "a.exr").read_text() == "ours" and (foreign / "deep" / "x.txt").read_text() == "x"
    with pytest.raises(confine.OutputError, match="not a folder"):
        confine.check_output(foreign / "a.exr", "render-asset")


# -- probe 5: a failed re-import destroyed the previous import's lights -------------------------------------------


@pytest.fixture(scope="module")
def nerf_scene(tmp_path_factory):
    base = tmp_path_factory.mktemp("outputs")
    make_curated(base / "curated")
    return export_object("nerf-synthetic", base / "curated", "obj_0000", base / "ns")


def test_failed_reimport_keeps_the_previous_import(nerf_scene, tmp_path, monkeypatch):
    results = tmp_path / "results"
    folder = import_scene("nerf-synthetic", nerf_scene, results, RES, 32, extra_inputs=2)
    meta = (folder / "meta.json").read_text()
    before = snapshot(results)
    assert any(k.startswith("envmaps/") for k in before)
    disk = FullDisk(monkeypatch, allow=10**9)  # count the EXR writes of an import
    import_scene("nerf-synthetic", nerf_scene, tmp_path / "count", RES, 32, extra_inputs=2)
    writes = disk.state["writes"]
    monkeypatch.undo()
    FullDisk(monkeypatch, allow=writes - 1)  # the last EXR an import writes is its light
    with pytest.raises(OSError) as err:
        import_scene("nerf-synthetic", nerf_scene, results, RES, 32, extra_inputs=2)
    assert err.value.errno == errno.ENOSPC and "no space left on device" in str(err.value)
    assert ".exr: cannot write" in str(err.value) and "\n" not in str(err.value)
    assert snapshot(results) == before and (folder / "meta.json").read_text() == meta


# -- render-asset on a full disk ----------------------------------------------------------------------------------


def tiny_asset(folder, n: int = 64, c: int = 4, **meta):
    """A renderable asset (Gaussians in the unit sphere, a small decoder) written with frng.apps.asset.save_asset."""
    from frng.apps.asset import save_asset
    from frng.gaussians import Gaussians
    from frng.render.shading import NeuralDecoder

    g = torch.Generator().manual_seed(0)
    q = torch.randn(n, 4, generator=g)
    gauss = Gaussians(
        torch.randn(n, 3, generator=g) * 0.3,
        q / q.norm(dim=1, keepdim=True),
        torch.exp(torch.randn(n, 3, generator=g) - 2.5),
        torch.rand(n, generator=g).clamp(0.2, 0.9),
    )
    torch.manual_seed(0)
    dec = NeuralDecoder(c, 16, 2, 0, cosine=False, attenuation=False)
    decoder = {
        "width": 16,
        "depth": 2,
        "input_encoding": "test",
        "feature_dim": c,
        "dir_freqs": 0,
        "cosine": False,
        "attenuation": False,
    }
    rig = {"camera_distance": 3.0, "fov_deg": 40.0, "resolution": 16}
    return save_asset(
        folder,
        gauss,
        torch.randn(n, c, generator=g),
        dec.state_dict(),
        {"object_id": "t", "decoder": decoder, "rig": rig, **meta},
    )


def _env(path, value: float = 1.0):
    envmap.write(path, np.full((8, 16, 3), value, np.float32))
    return path


def test_render_asset_full_disk_leaves_the_previous_output(tmp_path, capsys, monkeypatch):
    asset = tiny_asset(tmp_path / "asset")
    env = _env(tmp_path / "env.exr")
    out = tmp_path / "turn"
    argv = ["render-asset", asset, "--env", env, "--out", out, "--turntable", 3, "--spp", 4, "--video", "none"]
    code, lines = _run(argv, capsys)
    assert code == 0, lines
    before = snapshot(tmp_path)
    assert {"turn_000.exr", "turn_002.png", "cameras.json"} <= {k.split("/")[-1] for k in before}
    FullDisk(monkeypatch, allow=1)
    code, lines = _run(argv, capsys)
    assert code == 2 and len(lines) == 1, lines
    assert "turn_001.exr: cannot write: no space left on device" in lines[0], lines
    assert snapshot(tmp_path) == before, "the previous output changed or a staging folder was left"


def test_render_asset_refuses_a_foreign_folder_and_force_keeps_its_files(tmp_path, capsys):
    asset = tiny_asset(tmp_path / "asset")
    env = _env(tmp_path / "env.exr")
    out = tmp_path / "photos"
    out.mkdir()
    (out / "holiday.jpg").write_bytes(b"\xff\xd8\xffjpeg")
    argv = ["render-asset", asset, "--env", env, "--out", out, "--turntable", 2, "--spp", 2, "--video", "none"]
    code, lines = _run(argv, capsys)
    assert code == 2 and len(lines) == 1 and "--force" in lines[0], lines
    assert sorted(p.name for p in out.iterdir()) == ["holiday.jpg"]
    code, lines = _run([*argv, "--force"], capsys)
    assert code == 0, lines
    assert (out / "holiday.jpg").read_bytes() == b"\xff\xd8\xffjpeg" and (out / "turn_001.exr").exists()


# -- export -------------------------------------------------------------------------------------------------------


def test_export_adds_up_and_refuses_a_foreign_folder(tmp_path, capsys):
    results = tmp_path / "results"
    make_curated(results)
    cfg = write_config(tmp_path / "c.yaml", results)
    out = tmp_path / "exported"
    base = ["export", "--config", cfg, "--layout", "tensoir", "--object", "obj_0000", "--out", out]
    assert _run(base, capsys)[0] == 0
    assert _run([*base, "--scene", "second"], capsys)[0] == 0
    assert (out / "obj_0000" / "train_000" / "metadata.json").exists() and (out / "second" / "test_000").is_dir()
    foreign = tmp_path / "docs"
    foreign.mkdir()
    (foreign / "thesis.tex").write_text("x")
    code, lines = _run([*base[:-1], foreign], capsys)
    assert code == 2 and len(lines) == 1 and "--force" in lines[0], lines
    assert sorted(p.name for p in foreign.iterdir()) == ["thesis.tex"]
    code, lines = _run([*base, "--scene", "../escaped"], capsys)
    assert code == 2 and "plain name" in lines[0] and not (tmp_path / "escaped").exists(), lines


def test_reconstruct_export_object_refuses_a_foreign_folder(tmp_path, capsys):
    out = tmp_path / "mine"
    out.mkdir()
    (out / "cameras.json").write_text("{}")  # a file of the name the export writes: not replaced without --force
    cfg = write_config(tmp_path / "c.yaml", tmp_path / "results")
    code, lines = _run(["reconstruct", "--export-object", "obj_0000", "--out", out, "--config", cfg], capsys)
    assert code == 2 and len(lines) == 1 and "--force" in lines[0], lines
    assert (out / "cameras.json").read_text() == "{}" and [p.name for p in out.iterdir()] == ["cameras.json"]


# -- issue 87, probe 1: a forged manifest deleted the user's files -------------------------------------------------


def _forged(folder, files, command="reconstruct"):
    (folder / confine.MANIFEST).write_text(json.dumps({"command": command, "files": files}))


def test_a_forged_manifest_proves_nothing(tmp_path, capsys):
    """A manifest without hashes, with hashes of other content, or naming paths out of the folder owns nothing: the
    folder is refused without --force, and with --force (or a rerun) its files are all kept."""
    photos = tmp_path / "photos"
    photos.mkdir()
    cfg = write_config(tmp_path / "c.yaml", tmp_path / "results")
    outside = tmp_path / "outside.txt"
    outside.write_text("outside")
    for files in (
        ["thesis.txt", "sub/data.csv"],
        {"thesis.txt": "0" * 64, "sub/data.csv": hashlib.sha256(b"other").hexdigest()},
        {"../outside.txt": hashlib.sha256(b"outside").hexdigest()},
    ):
        v = tmp_path / "V"
        (v / "sub").mkdir(parents=True, exist_ok=True)
        (v / "thesis.txt").write_text("my thesis")
        (v / "sub" / "data.csv").write_text("1,2")
        _forged(v, files)
        before = snapshot(tmp_path)
        code, lines = _run(["reconstruct", "--images", photos, "--out", v, "--config", cfg], capsys)
        assert code == 2 and len(lines) == 1 and "--force" in lines[0], (files, lines)
        assert snapshot(tmp_path) == before, files
        m = confine.read_manifest(v)
        assert confine.owned_files(v, m) == {}, files


def test_a_rerun_replaces_only_unchanged_recorded_files(tmp_path):
    out = tmp_path / "out"
    with confine.staged_output(out, "render-asset") as stage:
        (stage / "sub").mkdir()
        (stage / "sub" / "a.exr").write_text("1")
        (stage / "b.exr").write_text("1")
    # the user edits a recorded file: refused (named), kept
    (out / "b.exr").write_text("edited")
    with pytest.raises(confine.OutputError, match=r"b\.exr changed since `frng render-asset` wrote it"):
        with confine.staged_output(out, "render-asset"):
            pass
    # --force: the changed file is replaced only where the new output writes it; a stale unchanged one goes
    with confine.staged_output(out, "render-asset", force=True) as stage:
        (stage / "b.exr").write_text("2")
    assert (out / "b.exr").read_text() == "2" and not (out / "sub").exists()
    # a file of the user's where the new output writes one: refused at the end, nothing changed
    (out / "c.exr").write_text("the user's")
    before = snapshot(tmp_path)
    with pytest.raises(confine.OutputError, match=r"holds c\.exr, which `frng render-asset` would write over"):
        with confine.staged_output(out, "render-asset") as stage:
            (stage / "b.exr").write_text("3")
            (stage / "c.exr").write_text("3")
    assert snapshot(tmp_path) == before
    # a recorded file replaced by a symlink to the user's file (same bytes): not owned, the target untouched
    mine = tmp_path / "mine.exr"
    mine.write_text("2")
    (out / "b.exr").unlink()
    (out / "b.exr").symlink_to(mine)
    with pytest.raises(confine.OutputError, match="changed since"):
        confine.check_output(out, "render-asset")
    with confine.staged_output(out, "render-asset", force=True) as stage:
        (stage / "b.exr").write_text("4")
    assert mine.read_text() == "2" and (out / "b.exr").read_text() == "4" and not (out / "b.exr").is_symlink()


# -- issue 87, probe 2: --force through a symlinked --out moved the target's files ---------------------------------


def test_force_writes_through_a_symlinked_out(tmp_path):
    target = tmp_path / "target"
    (target / "deep").mkdir(parents=True)
    (target / "notes.txt").write_text("notes")
    (target / "deep" / "x.csv").write_text("x")
    link = tmp_path / "link"
    link.symlink_to(target, target_is_directory=True)
    with pytest.raises(confine.OutputError, match="not empty"):
        with confine.staged_output(link, "reconstruct"):
            pass
    with confine.staged_output(link, "reconstruct", force=True) as stage:
        assert stage.resolve().parent == target.resolve()  # staged on the target's file system
        (stage / "asset.json").write_text("{}")
    assert link.is_symlink() and os.readlink(link) == str(target)
    assert (target / "notes.txt").read_text() == "notes" and (target / "deep" / "x.csv").read_text() == "x"
    assert (target / "asset.json").read_text() == "{}" and (target / confine.MANIFEST).is_file()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["link", "target"]  # no .old-* / .tmp-* left
    assert not [p for p in target.iterdir() if p.name.startswith((".tmp-", ".old-"))]
    # a rerun through the link (a previous output now): the target's files stay
    with confine.staged_output(link, "reconstruct") as stage:
        (stage / "asset.json").write_text('{"v": 2}')
    assert (target / "notes.txt").read_text() == "notes" and (target / "asset.json").read_text() == '{"v": 2}'


def test_a_symlinked_folder_inside_out_is_not_written_through(tmp_path):
    """An output folder whose sub-folder the new output writes into is a symlink out: refused, with --force the link
    is replaced and its target untouched."""
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    (elsewhere / "a.png").write_text("theirs")
    out = tmp_path / "out"
    with confine.staged_output(out, "export", merge=True) as stage:
        (stage / "x.json").write_text("1")
    (out / "obj").symlink_to(elsewhere, target_is_directory=True)
    with pytest.raises(confine.OutputError, match="holds obj,"):
        with confine.staged_output(out, "export", merge=True) as stage:
            (stage / "obj").mkdir()
            (stage / "obj" / "a.png").write_text("ours")
    with confine.staged_output(out, "export", force=True, merge=True) as stage:
        (stage / "obj").mkdir()
        (stage / "obj" / "a.png").write_text("ours")
    assert (elsewhere / "a.png").read_text() == "theirs" and not (out / "obj").is_symlink()
    assert (out / "obj" / "a.png").read_text() == "ours" and (out / "x.json").read_text() == "1"


def test_a_failed_move_in_undoes_itself(tmp_path, monkeypatch):
    out = tmp_path / "out"
    with confine.staged_output(out, "render-asset") as stage:
        for n in "abc":
            (stage / f"{n}.exr").write_text("1")
    (out / "mine.txt").write_text("mine")
    before = snapshot(tmp_path)
    real, calls = os.replace, {"n": 0}

    def flaky(src, dst):
        calls["n"] += 1
        if calls["n"] == 5:
            raise OSError(errno.EXDEV, "Invalid cross-device link")
        return real(src, dst)

    monkeypatch.setattr(confine.os, "replace", flaky)
    with pytest.raises(OSError):
        with confine.staged_output(out, "render-asset") as stage:
            for n in "abd":
                (stage / f"{n}.exr").write_text("2")
    monkeypatch.undo()
    assert snapshot(tmp_path) == before


# -- issue 87, probe 3: export --object ../../X read and wrote outside ----------------------------------------------


def test_ids_that_become_paths_are_plain(tmp_path, capsys):
    results = tmp_path / "a" / "b" / "results"
    make_curated(results)
    cfg = write_config(tmp_path / "c.yaml", results)
    x = tmp_path / "X"
    x.mkdir()
    (x / "mine.txt").write_text("mine")
    before = snapshot(tmp_path)
    out = tmp_path / "a" / "b" / "out"
    export = ["export", "--config", cfg, "--layout", "nerf-synthetic", "--out", out]
    for argv in (
        [*export, "--object", "../../../X"],
        [*export, "--object", "obj_0000", "--scene", ".."],
        ["reconstruct", "--export-object", "../x", "--out", out, "--config", cfg],
        ["view", "--object", "/etc", "--config", cfg],
    ):
        code, lines = _run(argv, capsys)
        assert code == 2 and len(lines) == 1, (argv, lines)
        assert "no path parts" in lines[0] or "plain name" in lines[0], lines
    assert snapshot(tmp_path) == before
    with pytest.raises(confine.UntrustedInputError, match="object id '../X'"):
        export_object("nerf-synthetic", results, "../X", tmp_path / "o")
