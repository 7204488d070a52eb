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
    assert confine.read_manifest(out) == {"command": "render-asset", "files": ["a.exr", "b.exr"]}
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
