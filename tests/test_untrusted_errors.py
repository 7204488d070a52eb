"""Every error a user's file can cause is one line naming the file (and the key or field), with the traceback only under
``frng --debug`` (issue 56, docs/reliability.md). Each probe of the issue is a case written here: model, backbone and
IDM files of the wrong shape, without keys or of the wrong kind; asset.json of the wrong kind or field types; a
truncated .hdr; importer fields of the wrong type; a text file named .png; a 12000 x 12000 PNG; all-black photos
(a warning); ``render-asset --resolution 8000``; a full disk; a copied results folder.
"""

from __future__ import annotations

import argparse
import errno
import json
import shutil
import struct
import zlib

import numpy as np
import pytest
import torch
from data_helpers import write_config
from test_benchmarks import RES
from test_untrusted_confinement import edit_orb_frames, exported  # noqa: F401 -- the exported benchmark folders (module fixture)
from test_untrusted_outputs import _env, _run, tiny_asset

from frng import cli, io
from frng.apps.asset import AssetError, AssetRenderer
from frng.benchmarks import BenchmarkError, import_scene
from frng.render import envmap


def _one_line(lines: list[str], *words: str) -> str:
    assert len(lines) == 1 and "Traceback" not in lines[0], lines
    assert all(w in lines[0] for w in words), (words, lines)
    return lines[0]


# -- model, backbone and IDM files ---------------------------------------------------------------------------------


def test_model_file_holding_a_list_or_missing_config(tmp_path):
    from frng.model.composed import FRNG
    from frng.priors.registry import LearnedIDMPrior

    p = tmp_path / "model.pt"
    io.save_torch([1, 2, 3], p)
    with pytest.raises(io.CorruptFileError, match=rf"^{p}: not a F-RNG model file \(it holds a list"):
        FRNG.load(p)
    io.save_torch({"kind": "learned", "state_dict": {"w": torch.ones(2)}}, p)
    with pytest.raises(io.CorruptFileError, match=rf"^{p}: IDM model file: key 'config' is missing"):
        LearnedIDMPrior(p)


@pytest.mark.parametrize(
    "state, words",
    [
        ({"weight": torch.ones(4, 3), "bias": torch.ones(4)}, "size mismatch for weight"),
        ({"weight": torch.ones(2, 3)}, 'Missing key(s) in state_dict: "bias"'),
    ],
)
def test_model_of_another_architecture_is_one_line_naming_it(tmp_path, capsys, state, words):
    """torch's load_state_dict error (which names no file) ends the stage in one line naming the file just loaded."""
    p = tmp_path / "backbone.pt"
    io.save_torch({"kind": "relitlrm", "config": {}, "state_dict": state}, p)

    def run(args):
        s = io.load_torch(p, "backbone model file")
        torch.nn.Linear(3, 2).load_state_dict(s["state_dict"])

    assert cli.run_stage("reconstruct", run, None) == 2
    err = capsys.readouterr().err.strip()
    line = _one_line(err.splitlines(), f"{p}: backbone model file does not fit its architecture", words)
    assert line.startswith("frng reconstruct: error:")


def test_debug_shows_the_traceback(tmp_path, capsys, monkeypatch):
    monkeypatch.setattr(cli, "DEBUG", False)  # restored after the test (main sets it)
    asset = tiny_asset(tmp_path / "a")
    argv = ["render-asset", asset, "--env", _env(tmp_path / "e.exr"), "--out", tmp_path / "o", "--resolution", 8000]
    code, lines = _run(argv, capsys)
    _one_line(lines, "--resolution 8000: must be 1..2048")
    from frng.apps.capture import CaptureError

    with pytest.raises(CaptureError, match="--resolution 8000"):
        cli.main(["--debug", *map(str, argv)])

    def run(args):
        raise ValueError("/x/y.json: something a loader did not expect\nsecond line")

    monkeypatch.setattr(cli, "DEBUG", False)
    assert cli.run_stage("import", run, None) == 2
    _one_line(capsys.readouterr().err.strip().splitlines(), "/x/y.json: something", "--debug")


# -- assets -------------------------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    "edit, words",
    [
        (lambda m: [m], "asset.json: not a JSON object (a list)"),
        (lambda m: {**m, "decoder": "mlp"}, "field 'decoder' must be a dict, got str"),
        (lambda m: {**m, "num_gaussians": "64"}, "field 'num_gaussians' must be a int"),
        (
            lambda m: {**m, "render": {"raster": {}, "shading": {"spp_infer": -4}}},
            "field 'render.shading.spp_infer' must be an integer in 1..4096, got -4",
        ),
        (lambda m: {**m, "decoder": {**m["decoder"], "width": 10**9}}, "field 'decoder.width' must be an integer"),
        (lambda m: {**m, "render": "fast"}, "field 'render' must be an object"),
    ],
)
def test_asset_json_errors_are_one_line(tmp_path, edit, words):
    asset = tiny_asset(tmp_path / "a")
    meta = json.loads((asset / "asset.json").read_text())
    (asset / "asset.json").write_text(json.dumps(edit(meta)))
    with pytest.raises(AssetError) as err:
        AssetRenderer(asset)
    assert words in str(err.value) and str(asset / "asset.json") in str(err.value) and "\n" not in str(err.value)


def test_render_asset_resolution_is_bounded_before_allocating(tmp_path, capsys):
    asset = tiny_asset(tmp_path / "a")
    env = _env(tmp_path / "e.exr")
    code, lines = _run(["render-asset", asset, "--env", env, "--out", tmp_path / "o", "--resolution", 8000], capsys)
    assert code == 2
    _one_line(lines, "--resolution 8000", "MAX_RESOLUTION")
    assert not (tmp_path / "o").exists()
    meta = json.loads((asset / "asset.json").read_text())
    meta["rig"]["resolution"] = 100000  # the asset's own rig size is bounded too
    (asset / "asset.json").write_text(json.dumps(meta))
    code, lines = _run(["render-asset", asset, "--env", env, "--out", tmp_path / "o", "--turntable", 2], capsys)
    assert code == 2
    _one_line(lines, "asset.json 'rig.resolution'", "100000x100000")


# -- maps and images ----------------------------------------------------------------------------------------------


def _radiance(path, width: int = 16, height: int = 8, body: bytes = b""):
    path.write_bytes(b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n" + f"-Y {height} +X {width}\n".encode() + body)
    return path


def test_truncated_hdr_is_one_line(tmp_path):
    p = _radiance(tmp_path / "sky.hdr", body=b"\x02\x02\x00\x10\x80")
    with pytest.raises(envmap.EnvMapError, match=rf"^{p}: cannot read Radiance HDR: truncated or corrupt") as err:
        envmap.read(p)
    assert "\n" not in str(err.value)
    header_only = (tmp_path / "cut.hdr").write_bytes(b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n")
    assert header_only
    with pytest.raises(envmap.EnvMapError, match=r"cut\.hdr: truncated or corrupt Radiance HDR"):
        envmap.read(tmp_path / "cut.hdr")


def _png_header(path, width: int, height: int):
    """A PNG whose header declares width x height (RGBA 8 bit) and whose data is a few bytes."""

    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF)

    ihdr = struct.pack(">IIBBBBB", width, height, 8, 6, 0, 0, 0)
    path.write_bytes(b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IDAT", zlib.compress(b"\0" * 8)))
    return path


def test_text_file_named_png_and_huge_png(tmp_path):
    from frng.apps.capture import CaptureError, read_image

    text = tmp_path / "photo.png"
    text.write_text("not an image\n")
    with pytest.raises(CaptureError, match=rf"^{text}: not a PNG file") as err:
        read_image(text)
    assert "\n" not in str(err.value)
    with pytest.raises(io.ImageError, match=rf"^{text}: not a PNG file"):
        io.read_png(text)
    huge = _png_header(tmp_path / "huge.png", 12000, 12000)
    with pytest.raises(CaptureError, match=rf"^{huge}: 12000x12000 image has more than 100000000 pixels"):
        read_image(huge)  # refused from the header: nothing is decoded (no 550 MB allocation)


def test_all_black_photos_warn(tmp_path, capsys):
    from frng.apps.capture import CaptureError
    from frng.apps.reconstruct import reconstruct
    from frng.plan import config as frng_config
    from frng.typedconfig import typed

    photos = tmp_path / "photos"
    rgba = np.zeros((32, 32, 4), np.float32)
    rgba[8:24, 8:24, 3] = 1.0  # an object in the alpha, black everywhere
    for k in range(2):
        io.write_png(photos / f"v{k}.png", rgba)
    config = typed(frng_config.load(write_config(tmp_path / "c.yaml", tmp_path / "results")))
    with pytest.raises(CaptureError, match="model missing"):  # no trained model here: after the warning
        reconstruct(photos, tmp_path / "asset", config, rig="paper")
    err = capsys.readouterr().err
    assert "warning:" in err and "every photo is black" in err and str(photos) in err, err


# -- importer fields of the wrong type ----------------------------------------------------------------------------


def test_importer_fields_of_the_wrong_type(exported, tmp_path):  # noqa: F811
    scene, tr = edit_orb_frames(exported, tmp_path, "transforms_train.json", 2, "file_path", 7)
    with pytest.raises(
        BenchmarkError, match=rf"^{tr}: field 'frames\[2\]\.file_path' must be a non-empty string, got 7"
    ):
        import_scene("orb", scene, tmp_path / "r", RES, 32)

    ti = exported["tensoir"]
    shutil.copytree(ti.parent, tmp_path / "ti")
    md = tmp_path / "ti" / ti.name / "train_001" / "metadata.json"
    m = json.loads(md.read_text())
    m["imw"] = "32px"
    md.write_text(json.dumps(m))
    with pytest.raises(BenchmarkError, match=rf"^{md}: field 'imw' must be a positive integer, got '32px'"):
        import_scene("tensoir", tmp_path / "ti" / ti.name, tmp_path / "r", RES, 32)

    md.write_text("[1, 2]")
    with pytest.raises(BenchmarkError, match=rf"^{md}: not a JSON object"):
        import_scene("tensoir", tmp_path / "ti" / ti.name, tmp_path / "r", RES, 32)


# -- a full disk, a copied results folder -------------------------------------------------------------------------


def test_full_disk_names_the_file_and_leaves_no_partial_file(tmp_path):
    target = tmp_path / "out" / "cameras.json"
    with pytest.raises(OSError) as err:
        with io.atomic_path(target) as tmp:
            tmp.write_text("{")
            raise OSError(errno.ENOSPC, "No space left on device")
    assert err.value.errno == errno.ENOSPC and str(target) in str(err.value)
    assert list((tmp_path / "out").iterdir()) == []

    def run(args):
        with io.atomic_path(target) as tmp:
            tmp.write_text("{")
            raise OSError(errno.ENOSPC, "No space left on device")

    import contextlib
    import io as pyio

    buf = pyio.StringIO()
    with contextlib.redirect_stderr(buf):
        assert cli.run_stage("render-asset", run, None) == 2
    _one_line(buf.getvalue().strip().splitlines(), str(target), "no space left on device")


def test_copied_results_folder_says_the_command(tmp_path):
    import yaml

    from frng.plan import config as frng_config
    from frng.plan.sections import ConfigError

    first = write_config(tmp_path / "a.yaml", tmp_path / "results")
    cfg = frng_config.load(first)
    frng_config.record(cfg, tmp_path / "results" / "config.yaml")
    shutil.copytree(tmp_path / "results", tmp_path / "copy")
    moved = yaml.safe_load(first.read_text())
    moved["results"] = str(tmp_path / "copy")
    (tmp_path / "b.yaml").write_text(yaml.safe_dump(moved))
    with pytest.raises(ConfigError) as err:
        frng_config.record(frng_config.load(tmp_path / "b.yaml"), tmp_path / "copy" / "config.yaml")
    assert "--config overwrite_config=true" in str(err.value) and "results" in str(err.value)


def test_stale_cache_is_one_line(capsys):
    """`frng train` on caches of another backbone raised StaleCacheError uncaught (issue 87): a stage ends in one line."""
    from frng import cli
    from frng.priors.cache import StaleCacheError

    def run(args):
        raise StaleCacheError("/r/cache/obj_0000.safetensors: made with another backbone; re-run `frng backbone-cache`")

    assert cli.run_stage("train", run, argparse.Namespace()) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [
        "frng train: error: /r/cache/obj_0000.safetensors: made with another backbone; re-run `frng backbone-cache`"
    ]
