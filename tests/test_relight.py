"""frng relight: the run plan, and bad input (missing view, wrong image size, corrupt EXR, env map not 2:1) ->
a clear error naming the file, nothing written. Bad-input cases run on a private copy of the smoke test object."""

import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from frng import io
from frng.apps import relight
from frng.plan import config as frng_config
from frng.typedconfig import typed

ROOT = Path(__file__).resolve().parent.parent


def test_runs_cover_ablation_k_and_views_sweeps():
    from frng.priors.cache import SWEEP_VIEWS

    config = frng_config.load(ROOT / "config" / "smoke.yaml")
    runs = {r.name: r for r in relight.runs(config, n_input_views=10)}
    for v in config["frng"]["variants"]:
        assert runs[v].views == relight.RIG_VIEWS and runs[v].method == "F-RNG"
    assert {f"full-v{V}" for V in SWEEP_VIEWS if V != relight.RIG_VIEWS} <= set(runs)
    assert all(runs[f"full-v{V}"].variant == "full" for V in SWEEP_VIEWS if V != relight.RIG_VIEWS)
    ks = {r.k_percent for r in runs.values() if r.method == "F-RNG" and r.views == relight.RIG_VIEWS}
    assert ks == {float(p) for p in config["frng"]["k_sweep"]}
    assert "k2" not in runs  # K = 2% is the full run itself
    assert runs[relight.BACKBONE].method == "backbone"
    # the quality ladder's row (f): the full model fed the G-buffers instead of the IDM's priors
    assert runs["full-oracle"].variant == "full" and runs["full-oracle"].priors == "oracle"
    assert all(r.priors == "idm" for name, r in runs.items() if name != "full-oracle")
    assert len({r.name for r in relight.runs(config, n_input_views=6)}) == len(runs) - 2  # no v8/v10 with 6 views


@pytest.fixture(scope="module")
def private_object(smoke_dataset, tmp_path_factory):
    """A results folder holding a real copy (not a link) of the smoke test object and the env maps."""
    from frng.plan import catalog

    src_path, src_config = smoke_dataset
    d = tmp_path_factory.mktemp("relight_bad")
    src = Path(src_config["results"])
    oid = catalog.plan(src_config).split("test")[0]
    return src, oid, d


def _fresh(private_object, name):
    import yaml

    src, oid, d = private_object
    res = d / name / "results"
    shutil.copytree(src / "objects" / oid, res / "objects" / oid)
    shutil.copytree(src / "envmaps", res / "envmaps")
    cfg = yaml.safe_load((ROOT / "config" / "smoke.yaml").read_text())
    cfg["results"] = str(res)
    path = d / name / "smoke.yaml"
    path.write_text(yaml.safe_dump(cfg))
    config = frng_config.load(path)
    meta = io.read_json(res / "objects" / oid / "meta.json")
    return path, config, oid, meta, res


def _input(res, oid, meta, k=1):
    return res / "objects" / oid / "inputs" / meta["input_lights"][0] / f"{meta['views']['inputs'][k]['name']}.exr"


def _corrupt_missing(res, oid, meta):
    p = _input(res, oid, meta)
    p.unlink()
    return p


def _corrupt_size(res, oid, meta):
    p = _input(res, oid, meta)
    io.write_exr(p, np.ones((16, 16, 4), np.float32), channels=["R", "G", "B", "A"])
    return p


def _corrupt_bytes(res, oid, meta):
    p = _input(res, oid, meta)
    p.write_bytes(b"not an exr" * 20)
    return p


def _corrupt_envmap(res, oid, meta):
    p = res / "envmaps" / f"{meta['target_lights'][0]}.exr"
    io.write_exr(p, np.ones((16, 16, 3), np.float32), channels=["R", "G", "B"])
    return p


@pytest.mark.parametrize(
    "corrupt, words",
    [
        (_corrupt_missing, "does not exist"),
        (_corrupt_size, "expected 32x32"),
        (_corrupt_bytes, "cannot read EXR"),
        (_corrupt_envmap, "2:1"),
    ],
)
def test_bad_input_names_the_file_and_writes_nothing(private_object, corrupt, words):
    path, config, oid, meta, res = _fresh(private_object, corrupt.__name__)
    relight.validate_inputs(relight.RelightJob.of(typed(config)), oid)  # the clean copy is fine
    bad = corrupt(res, oid, meta)
    with pytest.raises(relight.RelightError) as e:
        relight.relight(relight.RelightJob.of(typed(config)), oid)
    assert str(bad) in str(e.value) and words in str(e.value), str(e.value)
    assert not (res / "relight").exists(), "relight wrote something on bad input"


def test_cli_reports_bad_input(private_object):
    path, config, oid, meta, res = _fresh(private_object, "cli")
    bad = _corrupt_bytes(res, oid, meta)
    r = subprocess.run(
        [sys.executable, "-m", "frng", "relight", "--config", str(path), "--object", oid],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert r.returncode == 2 and str(bad) in r.stdout + r.stderr
    assert not (res / "relight").exists()


def test_bench_relight_reports_both_methods():
    """`frng bench relight` at smoke sizes and two resolutions: one JSON line each with both methods' costs and the
    shading's roofline (values, not timings, checked)."""
    import json

    r = subprocess.run(
        [
            sys.executable,
            "-m",
            "frng",
            "bench",
            "relight",
            "--configs",
            str(ROOT / "config" / "smoke.yaml"),
            "--resolution",
            "32",
            "48",
            "--passes",
            "1",
            "--lights",
            "2",
            "--target-views",
            "2",
            "--json",
        ],
        capture_output=True,
        text=True,
        timeout=300,
        cwd=ROOT,
    )
    assert r.returncode == 0, r.stdout + r.stderr
    rows = [json.loads(line) for line in r.stdout.strip().splitlines()]
    assert [row["resolution"] for row in rows] == [32, 48]
    from frng.plan import config as frng_config
    from frng.typedconfig import typed

    sc = typed(frng_config.load(ROOT / "config" / "smoke.yaml")).shading
    W, D = sc.decoder_width, sc.decoder_depth  # the bench times `full`: the paper's decoder, 3 outputs
    for row in rows:
        for key in (
            "reconstruction_s",
            "frng_ms_per_image",
            "frng_ms_per_image_amortised",
            "backbone_ms_per_image",
            "speedup",
            "gaussians",
            "pixels_per_image",
            "lit_pairs_per_image",
            "shade_gflops",
            "matmul_peak_gflops",
        ):
            assert np.isfinite(row[key]) and row[key] > 0, (key, row)
        assert row["lights"] == 2 and row["target_views"] == 2 and row["passes"] == 1
        # amortising the light-independent rasterization over 2 lights can only help
        assert row["frng_ms_per_image_amortised"] <= row["frng_ms_per_image"]
        # the smoke decoder (width W, depth D): (D - 1) W x W hidden layers + a W x 3 output, + W adds, per pair
        assert row["decoder_flops_per_pair"] == W + 2 * ((D - 1) * W * W + W * 3)
        assert row["lit_fraction"] == 1  # the paper's decoder decodes every (pixel, sample) pair
        assert row["lit_pairs_per_image"] <= row["pixels_per_image"] * row["spp"]
    assert rows[1]["pixels_per_image"] > rows[0]["pixels_per_image"]


# -- issue 12, point 6: an RGB-only input view and a training object are refused (no Blender: synthetic inputs) ----


def _synthetic_object(tmp_path, split):
    """A results folder with one object of the smoke plan's ``split`` whose input views are RGB-only EXRs."""
    import yaml

    from frng.plan import catalog

    cfg = yaml.safe_load((ROOT / "config" / "smoke.yaml").read_text())
    cfg["results"] = str(tmp_path / "results")
    path = tmp_path / "smoke.yaml"
    path.write_text(yaml.safe_dump(cfg))
    config = frng_config.load(path)
    spec = catalog.plan(config).object(catalog.plan(config).split(split)[0])
    root = tmp_path / "results" / "objects" / spec.id
    res = config["render"]["resolution"]
    views = [{"name": f"in_{k:02d}"} for k in range(2)]
    io.write_json(
        root / "meta.json",
        {
            "split": spec.split,
            "views": {"inputs": views},
            "input_lights": list(spec.input_lights),
            "target_lights": list(spec.target_lights),
        },
    )
    for v in views:
        io.write_exr(root / "inputs" / spec.input_lights[0] / f"{v['name']}.exr", np.ones((res, res, 3), np.float32))
    return config, spec.id, root


def test_rgb_only_input_view_is_refused(tmp_path):
    config, oid, root = _synthetic_object(tmp_path, "test")
    with pytest.raises(relight.RelightError) as e:
        relight.validate_inputs(relight.RelightJob.of(typed(config)), oid)
    assert "no alpha channel" in str(e.value) and str(root / "inputs") in str(e.value), str(e.value)


def test_training_object_is_refused(tmp_path):
    config, oid, root = _synthetic_object(tmp_path, "train")
    with pytest.raises(relight.RelightError) as e:
        relight.validate_inputs(relight.RelightJob.of(typed(config)), oid)
    assert repr(oid) in str(e.value) and "'train' split" in str(e.value), str(e.value)


def test_object_curated_as_training_is_refused(tmp_path):
    """meta.json says train although the plan says test (curated under another config): refused, naming the file."""
    config, oid, root = _synthetic_object(tmp_path, "test")
    meta = io.read_json(root / "meta.json")
    io.write_json(root / "meta.json", {**meta, "split": "train"})
    with pytest.raises(relight.RelightError) as e:
        relight.validate_inputs(relight.RelightJob.of(typed(config)), oid)
    assert str(root / "meta.json") in str(e.value) and "'train' split" in str(e.value), str(e.value)
