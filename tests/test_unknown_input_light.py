"""The paper's task: at test time a model gets the input photos, their cameras and masks, and the target light; never
the input views' light. ``frng relight`` of the smoke test object with the input light's env map replaced by another
map writes bit-identical images for every run but the labelled oracle ``plus-known-light`` (which must change: the
test can fail)."""

import subprocess
from pathlib import Path

import numpy as np
import pytest
from conftest import smoke_results, venv_bin

from frng import io
from frng.plan import catalog
from frng.plan.layout import Layout
from frng.plan.variants import KNOWN_LIGHT_RUN
from frng.render import envmap

SHARED = ("objects", "backbone", "idm", "priors", "models")


def _relight(config: Path, oid: str) -> None:
    cmd = [venv_bin("frng"), "relight", "--config", str(config), "--object", oid]
    r = subprocess.run(cmd, capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, (r.stdout + r.stderr)[-3000:]


def _images(results: Path, oid: str) -> dict[str, dict[str, np.ndarray]]:
    """{run: {light/view: linear RGBA}} of every relighting run of ``oid``."""
    out = {}
    for run_dir in sorted((results / "relight").iterdir()):
        obj = run_dir / oid
        if not obj.is_dir():
            continue
        out[run_dir.name] = {
            str(p.relative_to(obj)): io.read_rgba(p) for p in sorted(obj.glob("*/*.exr")) if p.parent.name != "asset"
        }
    return out


def test_no_test_time_path_reads_the_input_light(smoke_pipeline, smoke_dataset, tmp_path):
    src = Path(smoke_pipeline)
    _, config = smoke_dataset
    oid = catalog.plan(config).split("test")[0]
    light_in = io.read_json(Layout(src).object_meta(oid))["input_lights"][0]
    runs = {}
    for case in ("given", "replaced"):
        folder = tmp_path / case
        path, _ = smoke_results(smoke_dataset, folder, link=SHARED)
        results = folder / "results"
        (results / "envmaps").mkdir()
        for f in (src / "envmaps").iterdir():  # a real copy: the replaced case rewrites one map
            (results / "envmaps" / f.name).symlink_to(f)
        if case == "replaced":
            target = Path(Layout(results).envmap(light_in))
            original = envmap.read(target)
            target.unlink()
            # another light: the map turned half around and tinted, at the same size
            other = envmap.rotate_z(original, 180.0) * np.array([0.4, 0.8, 1.6], np.float32)
            envmap.write(target, other.astype(np.float32))
        _relight(path, oid)
        runs[case] = _images(results, oid)
    given, replaced = runs["given"], runs["replaced"]
    assert set(given) == set(replaced) and KNOWN_LIGHT_RUN in given and "full" in given and "backbone" in given
    for run, images in given.items():
        assert images and set(images) == set(replaced[run]), run
        same = all(np.array_equal(images[k], replaced[run][k]) for k in images)
        if run == KNOWN_LIGHT_RUN:  # the oracle told the input light: it must see the change
            assert not same, f"{run}: the oracle run did not read the input light"
        else:
            assert same, f"{run}: its images changed with the input views' light (a test-time path reads it)"


@pytest.mark.parametrize("height", [16, 32])
def test_reference_light_is_one_soft_sky(height):
    """E_0 (cache light 0) is the same map for every object: unit mean radiance, brighter at the zenith than at the
    horizon, a dim uniform ground, no azimuthal structure."""
    import torch

    e = envmap.reference_light(height)
    assert e.shape == (height, 2 * height, 3) and torch.isfinite(e).all()
    w = envmap.pixel_solid_angles(height, 2 * height)
    assert float((e[..., 0] * w).sum() / w.sum()) == pytest.approx(1.0, rel=1e-5)
    assert float(e[0, 0, 0]) > float(e[height // 2 - 1, 0, 0]) > float(e[-1, 0, 0]) > 0
    assert torch.allclose(e, e[:, :1].expand_as(e))
