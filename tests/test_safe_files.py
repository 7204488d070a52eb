"""Loading a file never runs code, and intermediate files are checked and named (issue 24, items 1, 3, 4, 5, 8, 9).

- 1: a crafted pickle placed as a model, checkpoint, prior or cache is refused with a clear error and runs nothing
  (the payload would only write a marker file in the test's folder); real files keep loading, random states too;
- 3: truncated caches / model files name the file; the training-set index's sizes and hashes are checked;
- 4: RGB-only views are refused on the training side and by the metrics (alpha is the object's mask);
- 5: safetensors outputs get the permissions an ordinary open gives;
- 8: the same object saved twice gives the same bytes (no random temporary name inside the zip);
- 9: config cross-key checks; a full disk names the file and the cause; a huge-header EXR; ASCII-PLY errors.
"""

from __future__ import annotations

import builtins
import copy
import hashlib
import os
import pickle
import random
import struct
import time
from pathlib import Path

import numpy as np
import pytest
import torch

from frng import io


class Payload:
    """Unpickling this runs ``exec``: it writes ``marker``."""

    def __init__(self, marker: Path):
        self.marker = str(marker)

    def __reduce__(self):
        return builtins.exec, (f"open({self.marker!r}, 'w').write('ran')",)


def _crafted(tmp_path: Path, name: str, zipped: bool) -> tuple[Path, Path]:
    marker = tmp_path / f"marker-{name}-{zipped}"
    path = tmp_path / f"{'zip' if zipped else 'raw'}" / name
    path.parent.mkdir(exist_ok=True)
    obj = {"kind": "frng", "config": {}, "state_dict": {}, "x": Payload(marker)}  # the payload runs on load
    if zipped:
        torch.save(obj, path)  # a torch zip whose data.pkl calls exec
    else:
        path.write_bytes(pickle.dumps(obj))
    return path, marker


@pytest.mark.filterwarnings("ignore:Detected pickle protocol")
@pytest.mark.parametrize("zipped", [True, False])
def test_crafted_pickles_run_nothing(tmp_path, zipped):
    from frng.checkpoint import load_resumable
    from frng.model.composed import FRNG
    from frng.priors import LearnedIDMPrior, load_backbone
    from frng.priors.cache import load_backbone_cache, load_idm_priors

    # a model.pt (F-RNG), the priors' model files (backbone, IDM)
    for name, load in [("model.pt", FRNG.load), ("backbone.pt", load_backbone), ("idm.pt", LearnedIDMPrior)]:
        path, marker = _crafted(tmp_path, name, zipped)
        with pytest.raises(io.CorruptFileError, match="refusing to load") as e:
            load(path)
        assert str(path) in str(e.value) and not marker.exists()
    # a checkpoint.pt beside a training job: not resumed, said why, nothing ran
    out = tmp_path / "run"
    out.mkdir()
    path, marker = _crafted(tmp_path, "checkpoint.pt", zipped)
    os.replace(path, out / "checkpoint.pt")
    state, why = load_resumable(out, "digest", 10)
    assert state is None and str(out / "checkpoint.pt") in why and "refusing" in why and not marker.exists()
    # caches and IDM priors (safetensors): named, nothing ran
    real_model, _ = _crafted(tmp_path, "unused.pt", zipped)
    for name, load in [
        ("cache.safetensors", lambda p: load_backbone_cache(p, real_model)),
        ("prior.safetensors", load_idm_priors),
    ]:
        path, marker = _crafted(tmp_path, name, zipped)
        with pytest.raises(io.CorruptFileError) as e:
            load(path)
        assert str(path) in str(e.value) and not marker.exists()


def test_crafted_lpips_weights_run_nothing(tmp_path, monkeypatch):
    from frng import perceptual

    marker = tmp_path / "marker-lpips"
    weights = tmp_path / "weights"
    weights.mkdir()
    (weights / perceptual._CKPT["alex"]).write_bytes(pickle.dumps({"x": Payload(marker)}))
    monkeypatch.setenv(perceptual.WEIGHTS_ENV, str(weights))
    perceptual._load_state.cache_clear()
    try:
        with pytest.raises(ValueError, match="refusing to load LPIPS weights") as e:
            perceptual._load_state("alex")
        assert str(weights) in str(e.value) and not marker.exists()
    finally:
        perceptual._load_state.cache_clear()


def test_real_checkpoint_state_loads_safely(tmp_path):
    """What a checkpoint holds (model, optimiser, every kind of random state, history) survives the safe load
    and restores the generators exactly."""
    from frng.io import save_torch
    from frng.seeding import rng_state, set_rng_state

    model = torch.nn.Linear(3, 2)
    opt = torch.optim.AdamW(model.parameters(), lr=1e-3)
    model(torch.randn(4, 3)).sum().backward()
    opt.step()
    rngs = {
        "py": random.Random(1),
        "torch": torch.Generator().manual_seed(2),
        "np": np.random.default_rng(3),
        "mt": np.random.Generator(np.random.MT19937(4)),
        "legacy": np.random.RandomState(5),
    }
    np.random.seed(6)
    state = {
        "format": 2,
        "step": 3,
        "model": model.state_dict(),
        "optimizer": opt.state_dict(),
        "rng": [rng_state("cpu", rngs)],
        "history": [{"step": 1, "total": 0.5}],
        "elapsed": 1.5,
        "fingerprint": {"a": [1, 2.0, "x", None, True]},
    }
    save_torch(state, tmp_path / "checkpoint.pt")

    def draws():  # one number from every generator the checkpoint holds
        return (
            random.random(),
            np.random.rand(),
            torch.rand(1).item(),
            rngs["py"].random(),
            torch.rand(1, generator=rngs["torch"]).item(),
            rngs["np"].random(),
            rngs["mt"].random(),
            rngs["legacy"].rand(),
        )

    expect = draws()
    back = io.load_torch(tmp_path / "checkpoint.pt", "checkpoint")
    set_rng_state(back["rng"][0], "cpu", rngs)
    assert draws() == expect
    opt.load_state_dict(back["optimizer"])
    model.load_state_dict(back["model"])


# -- 3: truncated / corrupt intermediate files are named ---------------------------------------------------


def test_truncated_files_are_named(tmp_path):
    from frng.model.composed import FRNG
    from frng.priors.cache import _save, load_idm_priors

    cache = tmp_path / "priors" / "obj.safetensors"
    _save({"a": torch.zeros(100)}, {"version": "1"}, cache)
    cache.write_bytes(cache.read_bytes()[:5])
    with pytest.raises(io.CorruptFileError, match="truncated or corrupt") as e:
        load_idm_priors(cache)
    assert str(cache) in str(e.value)
    model = tmp_path / "model.pt"
    io.save_torch({"kind": "frng", "state_dict": {"w": torch.zeros(1000)}}, model)
    model.write_bytes(model.read_bytes()[:300])
    with pytest.raises(io.CorruptFileError, match="truncated or corrupt") as e:
        FRNG.load(model)
    assert str(model) in str(e.value)


def test_training_set_index_is_checked(tmp_path):
    files = [tmp_path / f"o{i}.safetensors" for i in range(3)]
    for i, f in enumerate(files):
        f.write_bytes(bytes([i]) * 50)
    index = io.write_file_index(files, tmp_path / "train_set.json")
    assert io.check_file_index(index) == 3
    files[1].write_bytes(b"x" * 20)  # truncated
    with pytest.raises(io.CorruptFileError, match="recorded 50") as e:
        io.check_file_index(index)
    assert str(files[1]) in str(e.value)
    files[1].write_bytes(b"y" * 50)  # same size, other bytes
    with pytest.raises(io.CorruptFileError, match="sha256") as e:
        io.check_file_index(index)
    assert str(files[1]) in str(e.value)
    old_ns = files[0].stat().st_mtime_ns - 10**9
    os.utime(files[1], ns=(old_ns, old_ns))  # replaced, its mtime set back (cp -p): the inode's ctime still tells
    with pytest.raises(io.CorruptFileError, match="sha256"):
        io.check_file_index(index)


def test_training_set_index_skips_hashing_files_older_than_the_index(tmp_path, monkeypatch):
    import hashlib

    files = [tmp_path / f"o{i}.safetensors" for i in range(3)]
    for i, f in enumerate(files):
        f.write_bytes(bytes([i]) * 50)
    index = io.write_file_index(files, tmp_path / "train_set.json")
    later = max(max(f.stat().st_ctime_ns, f.stat().st_mtime_ns) for f in files) + 10**9
    os.utime(index, ns=(later, later))  # written a second after the files: they cannot have changed since
    hashed = []
    real = hashlib.sha256
    monkeypatch.setattr(hashlib, "sha256", lambda *a: hashed.append(1) or real(*a))
    assert io.check_file_index(index) == 3 and hashed == []
    assert io.check_file_index(index, hashes=True) == 3
    os.utime(index, ns=(later - 2 * 10**9,) * 2)  # an index older than its files: every file is hashed
    assert io.check_file_index(index) == 3 and len(hashed) == 3


# -- 4: RGB-only views --------------------------------------------------------------------------------------


def test_rgb_only_views_are_refused(tmp_path):
    from frng import metrics
    from frng.data.dataset import ObjectData

    root = tmp_path / "objects" / "o"
    view = {"name": "v0", "c2w": np.eye(4).tolist(), "intrinsics": [10, 10, 4, 4]}
    obj = ObjectData(
        root,
        {
            "id": "o",
            "views": {"inputs": [view]},
            "input_lights": ["L"],
            "target_lights": [],
            "split": "train",
            "material_class": "diffuse",
        },
    )
    rgb = np.full((16, 16, 3), 0.5, np.float32)
    path = Path(obj.files.image("inputs", "L", "v0"))
    io.write_exr(path, rgb)
    with pytest.raises(io.ImageError, match="no alpha") as e:
        obj.images("inputs", "L")
    assert str(path) in str(e.value)
    rgba = tmp_path / "rgba.exr"
    io.write_exr(rgba, np.concatenate([rgb, np.ones((16, 16, 1), np.float32)], -1))
    with pytest.raises(io.ImageError, match="no alpha"):
        metrics.evaluate_files(rgba, path)
    with pytest.raises(io.ImageError, match="no alpha"):
        metrics.evaluate_files(path, rgba)


# -- 5: permissions ------------------------------------------------------------------------------------------


def test_safetensors_outputs_follow_the_umask(tmp_path):
    from frng.apps.asset import DECODER_FILE, save_asset
    from frng.gaussians import Gaussians
    from frng.priors.cache import _save

    old = os.umask(0o022)
    try:
        _save({"a": torch.zeros(3)}, {"version": "1"}, tmp_path / "c.safetensors")
        assert (tmp_path / "c.safetensors").stat().st_mode & 0o777 == 0o644
        n = 4
        g = Gaussians(
            means=torch.zeros(n, 3),
            quats=torch.tensor([[1.0, 0, 0, 0]]).repeat(n, 1),
            scales=torch.full((n, 3), 0.1),
            opacities=torch.full((n,), 0.5),
        )
        dec = torch.nn.Linear(2, 3).state_dict()
        folder = save_asset(
            tmp_path / "asset",
            g,
            torch.zeros(n, 2),
            dec,
            {"object_id": "o", "decoder": {"width": 1, "depth": 1, "input_encoding": "x"}},
        )
        assert (folder / DECODER_FILE).stat().st_mode & 0o777 == 0o644
        io.save_torch({"a": 1}, tmp_path / "m.pt")
        assert (tmp_path / "m.pt").stat().st_mode & 0o777 == 0o644
    finally:
        os.umask(old)


# -- 8: same object, same bytes ------------------------------------------------------------------------------


def test_same_object_same_bytes(tmp_path):
    from frng.io import save_torch

    obj = {"kind": "frng", "state_dict": {"w": torch.arange(10.0)}, "config": {"a": 1}}
    save_torch(obj, tmp_path / "a" / "model.pt")
    save_torch(obj, tmp_path / "b" / "model.pt")
    digest = [hashlib.sha256((tmp_path / d / "model.pt").read_bytes()).hexdigest() for d in "ab"]
    assert digest[0] == digest[1]


def test_identical_retrain_same_model_bytes(tmp_path):
    """Two identical trainings (the IDM's, a few steps) write byte-identical model.pt files."""
    from test_training_loop import _config, _objects, train_idm

    from frng.hashing import file_sha256

    for d in "ab":
        train_idm(_config(), _objects(), tmp_path / d)
    assert file_sha256(tmp_path / "a" / "model.pt") == file_sha256(tmp_path / "b" / "model.pt")


# -- 9: late or unclear errors -------------------------------------------------------------------------------


def test_cross_key_checks():
    from frng.plan import config as frng_config

    base = frng_config.read_yaml(Path(__file__).parent.parent / "config" / "smoke.yaml")
    for section, bad, key in [
        ("shading", {"spp_train": 8, "spp_grad": 16}, "shading.spp_grad"),
        ("backbone", {"near": 5.0, "far": 4.0}, "backbone.near"),
    ]:
        cfg = copy.deepcopy(base)
        cfg.setdefault(section, {}).update(bad)
        with pytest.raises(frng_config.ConfigError, match=key.replace(".", r"\.")):
            frng_config.validate(cfg)


def test_full_disk_names_the_file(tmp_path, monkeypatch):
    import OpenEXR

    def full(self, *a, **k):
        raise RuntimeError("basic_ios::clear: iostream error")

    monkeypatch.setattr(OpenEXR.File, "write", full)
    st = os.statvfs(tmp_path)
    fake = os.statvfs_result(
        (st.f_bsize, st.f_frsize, st.f_blocks, 0, 0, st.f_files, st.f_ffree, st.f_favail, st.f_flag, st.f_namemax)
    )
    monkeypatch.setattr(io.os, "statvfs", lambda p: fake)
    path = tmp_path / "img.exr"
    with pytest.raises(OSError, match="no space left on device") as e:
        io.write_exr(path, np.zeros((4, 4, 4), np.float32))
    assert str(path) in str(e.value) and not path.exists()
    assert not any(p.name.startswith(".tmp-") for p in tmp_path.iterdir())


def test_full_disk_names_the_cache(tmp_path, monkeypatch):
    import safetensors.torch

    from frng.priors.cache import _save

    def full(*a, **k):
        raise OSError(28, "No space left on device (os error 28)")

    monkeypatch.setattr(safetensors.torch, "save", full)
    path = tmp_path / "cache" / "obj.safetensors"
    with pytest.raises(OSError, match="no space left on device") as e:
        _save({"a": torch.zeros(2)}, {}, path)
    assert str(path) in str(e.value) and not path.exists()


def test_huge_header_exr_says_so(tmp_path):
    path = tmp_path / "h.exr"
    io.write_exr(path, np.zeros((4, 4, 4), np.float32))
    data = bytearray(path.read_bytes())
    key = b"dataWindow\x00box2i\x00"
    i = data.find(key) + len(key) + 4
    data[i : i + 16] = struct.pack("<4i", 0, 0, 200000, 200000)  # a 200001^2 data window
    path.write_bytes(bytes(data))
    with pytest.raises(io.ImageError, match="200001x200001") as e:
        io.read_exr_channels(path)
    assert str(path) in str(e.value) and "has no channels" not in str(e.value)


def test_ascii_ply_parse_error_names_the_file(tmp_path):
    from frng.apps.asset import AssetError, read_ply

    path = tmp_path / "bad.ply"
    path.write_text(
        "ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\nproperty float y\nend_header\n1 2\n3 oops\n"
    )
    with pytest.raises(AssetError, match="oops") as e:
        read_ply(path)
    assert str(path) in str(e.value) and "vertex 1" in str(e.value)


def test_stage_errors_are_one_line(capsys):
    """A corrupt file, an RGB-only view or a full disk ends a stage in one line naming the file, not a traceback."""
    from frng import cli

    for err in [
        io.CorruptFileError("/r/backbone/cache/o.safetensors: cannot read cache: truncated or corrupt"),
        io.ImageError("/r/objects/o/inputs/L/in_00.exr: no alpha channel"),
        io.write_failure("/r/x.safetensors", OSError(28, "No space left on device (os error 28)")),
    ]:

        def run(args, err=err):
            raise err

        assert cli.run_stage("train", run, None) == 2
        line = capsys.readouterr().err.strip()
        assert line.startswith("frng train: error: /r/") and "\n" not in line


def test_file_hash_memo_follows_the_file(tmp_path):
    """file_sha256 is memoised per file identity; a rewritten file (even fast, same size) is hashed again."""
    from frng.hashing import file_sha256

    f = tmp_path / "model.pt"
    f.write_bytes(b"a" * 64)
    first = file_sha256(f)
    assert first == hashlib.sha256(b"a" * 64).hexdigest()
    f.write_bytes(b"b" * 64)  # in place, same size, within the file system's timestamp tick
    assert file_sha256(f) == hashlib.sha256(b"b" * 64).hexdigest()
    old = time.time_ns() - 10 * 10**9  # an old, settled file: memoised, still right
    os.utime(f, ns=(old, old))
    assert file_sha256(f) == file_sha256(f) == hashlib.sha256(b"b" * 64).hexdigest()
